#include "body/procedural_body.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <filesystem>
#include <functional>
#include <map>
#include <queue>
#include <stdexcept>
#include <utility>
#include <vector>

#include <ATen/Functions.h>
#include <ATen/TensorOperators.h>

#include "body/skeleton.h"
#include "io/npz.h"

namespace sfgs::body {
namespace {

// ---- small geometry ------------------------------------------------------------------------------------------

using Vec3 = std::array<double, 3>;
Vec3 operator+(const Vec3& a, const Vec3& b) { return {a[0] + b[0], a[1] + b[1], a[2] + b[2]}; }
Vec3 operator-(const Vec3& a, const Vec3& b) { return {a[0] - b[0], a[1] - b[1], a[2] - b[2]}; }
Vec3 operator*(double s, const Vec3& a) { return {s * a[0], s * a[1], s * a[2]}; }
double dot(const Vec3& a, const Vec3& b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }
Vec3 cross(const Vec3& a, const Vec3& b) {
  return {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
}
Vec3 normalized(const Vec3& a) { return (1.0 / std::sqrt(dot(a, a))) * a; }
Vec3 mirrored(const Vec3& a) { return {-a[0], a[1], a[2]}; }
double radians(double degrees) { return degrees * M_PI / 180.0; }

// Heights below are above the floor, which sits at this y so that the pelvis is near y = 0 as in SMPL-X.
constexpr double kFloorY = -0.93;
Vec3 at_height(double x, double h, double z) { return {x, h + kFloorY, z}; }

namespace J = smplx_joint;
using JointWeights = std::vector<std::pair<int64_t, double>>;

// ---- polygon meshes, Catmull-Clark ----------------------------------------------------------------------------

struct PolyMesh {
  std::vector<std::vector<int64_t>> faces;
  std::vector<int64_t> charts;  // per face: the UV chart it belongs to
  int64_t vertex_count = 0;
};

// Fine vertex rows[k] receives values[k] times coarse vertex cols[k]: subdivision is linear in vertex data.
struct Stencil {
  std::vector<int64_t> rows, cols;
  std::vector<double> values;
  int64_t fine_count = 0;

  at::Tensor apply(const at::Tensor& coarse) const {
    const at::Tensor r = at::tensor(rows, at::kLong), c = at::tensor(cols, at::kLong);
    const at::Tensor w = at::tensor(values, at::kDouble).unsqueeze(1);
    return at::zeros({fine_count, coarse.size(1)}, coarse.options()).index_add_(0, r, coarse.index_select(0, c) * w);
  }
};

struct Subdivided {
  PolyMesh mesh;
  Stencil stencil;
  std::vector<int64_t> mirror;
};

using Edge = std::pair<int64_t, int64_t>;
Edge undirected(int64_t a, int64_t b) { return a < b ? Edge{a, b} : Edge{b, a}; }

// One Catmull-Clark step on a closed polygon mesh. Fine vertices: vertex points (old indices), then edge points,
// then face points. Face (v0 .. vk-1) becomes the quads (v_i, e(v_i v_i+1), f, e(v_i-1 v_i)), which keep its
// orientation and chart. The mirror map follows combinatorially, so symmetry survives exactly.
Subdivided catmull_clark(const PolyMesh& coarse, const std::vector<int64_t>& mirror) {
  const int64_t v = coarse.vertex_count;
  std::map<Edge, int64_t> edge_index;
  std::vector<Edge> edges;
  std::vector<std::vector<int64_t>> edge_faces, vertex_faces(v), vertex_edges(v);
  for (size_t f = 0; f < coarse.faces.size(); ++f) {
    const auto& face = coarse.faces[f];
    for (size_t i = 0; i < face.size(); ++i) {
      const Edge e = undirected(face[i], face[(i + 1) % face.size()]);
      auto [it, inserted] = edge_index.emplace(e, static_cast<int64_t>(edges.size()));
      if (inserted) {
        edges.push_back(e);
        edge_faces.emplace_back();
        vertex_edges[e.first].push_back(it->second);
        vertex_edges[e.second].push_back(it->second);
      }
      edge_faces[it->second].push_back(static_cast<int64_t>(f));
      vertex_faces[face[i]].push_back(static_cast<int64_t>(f));
    }
  }
  for (const auto& faces : edge_faces) {
    if (faces.size() != 2) throw std::logic_error("procedural body: the cage is not a closed 2-manifold");
  }
  const int64_t e_count = static_cast<int64_t>(edges.size());
  Subdivided out;
  out.stencil.fine_count = v + e_count + static_cast<int64_t>(coarse.faces.size());
  const auto emit = [&](int64_t row, const std::map<int64_t, double>& terms) {
    for (const auto& [col, value] : terms) {
      out.stencil.rows.push_back(row);
      out.stencil.cols.push_back(col);
      out.stencil.values.push_back(value);
    }
  };
  for (int64_t i = 0; i < v; ++i) {
    // (Q + 2R + (n - 3) S) / n: Q averages the adjacent face points, R the incident edge midpoints.
    const double n = static_cast<double>(vertex_edges[i].size());
    std::map<int64_t, double> terms;
    for (int64_t f : vertex_faces[i]) {
      const auto& face = coarse.faces[f];
      for (int64_t u : face) terms[u] += 1.0 / (n * n * static_cast<double>(face.size()));
    }
    for (int64_t e : vertex_edges[i]) {
      terms[edges[e].first] += 1.0 / (n * n);
      terms[edges[e].second] += 1.0 / (n * n);
    }
    terms[i] += (n - 3.0) / n;
    emit(i, terms);
  }
  for (int64_t e = 0; e < e_count; ++e) {
    std::map<int64_t, double> terms;
    terms[edges[e].first] += 0.25;
    terms[edges[e].second] += 0.25;
    for (int64_t f : edge_faces[e]) {
      const auto& face = coarse.faces[f];
      for (int64_t u : face) terms[u] += 0.25 / static_cast<double>(face.size());
    }
    emit(v + e, terms);
  }
  std::map<std::vector<int64_t>, int64_t> face_by_vertices;
  for (size_t f = 0; f < coarse.faces.size(); ++f) {
    std::map<int64_t, double> terms;
    for (int64_t u : coarse.faces[f]) terms[u] += 1.0 / static_cast<double>(coarse.faces[f].size());
    emit(v + e_count + static_cast<int64_t>(f), terms);
    std::vector<int64_t> key = coarse.faces[f];
    std::sort(key.begin(), key.end());
    face_by_vertices[key] = static_cast<int64_t>(f);
  }

  out.mesh.vertex_count = out.stencil.fine_count;
  for (size_t f = 0; f < coarse.faces.size(); ++f) {
    const auto& face = coarse.faces[f];
    const int64_t k = static_cast<int64_t>(face.size());
    const int64_t face_point = v + e_count + static_cast<int64_t>(f);
    for (int64_t i = 0; i < k; ++i) {
      const int64_t next = v + edge_index.at(undirected(face[i], face[(i + 1) % k]));
      const int64_t previous = v + edge_index.at(undirected(face[(i + k - 1) % k], face[i]));
      out.mesh.faces.push_back({face[i], next, face_point, previous});
      out.mesh.charts.push_back(coarse.charts[f]);
    }
  }
  out.mirror.resize(out.stencil.fine_count);
  for (int64_t i = 0; i < v; ++i) out.mirror[i] = mirror[i];
  for (int64_t e = 0; e < e_count; ++e)
    out.mirror[v + e] = v + edge_index.at(undirected(mirror[edges[e].first], mirror[edges[e].second]));
  for (size_t f = 0; f < coarse.faces.size(); ++f) {
    std::vector<int64_t> key;
    for (int64_t u : coarse.faces[f]) key.push_back(mirror[u]);
    std::sort(key.begin(), key.end());
    out.mirror[v + e_count + static_cast<int64_t>(f)] = v + e_count + face_by_vertices.at(key);
  }
  return out;
}

bool has_directed_edge(const std::vector<int64_t>& face, int64_t a, int64_t b) {
  for (size_t i = 0; i < face.size(); ++i)
    if (face[i] == a && face[(i + 1) % face.size()] == b) return true;
  return false;
}

// Gives every face of each connected component the same orientation, outward (positive enclosed volume).
void orient_outward(PolyMesh& mesh, const std::vector<Vec3>& positions) {
  std::map<Edge, std::vector<int64_t>> faces_of_edge;
  for (size_t f = 0; f < mesh.faces.size(); ++f)
    for (size_t i = 0; i < mesh.faces[f].size(); ++i)
      faces_of_edge[undirected(mesh.faces[f][i], mesh.faces[f][(i + 1) % mesh.faces[f].size()])].push_back(
          static_cast<int64_t>(f));
  std::vector<bool> done(mesh.faces.size(), false);
  for (size_t seed = 0; seed < mesh.faces.size(); ++seed) {
    if (done[seed]) continue;
    std::vector<int64_t> component;
    std::queue<int64_t> queue;
    queue.push(static_cast<int64_t>(seed));
    done[seed] = true;
    while (!queue.empty()) {
      const int64_t f = queue.front();
      queue.pop();
      component.push_back(f);
      const auto face = mesh.faces[f];
      for (size_t i = 0; i < face.size(); ++i) {
        const int64_t a = face[i], b = face[(i + 1) % face.size()];
        for (int64_t g : faces_of_edge.at(undirected(a, b))) {
          if (g == f) continue;
          const bool same_direction = has_directed_edge(mesh.faces[g], a, b);
          if (done[g]) {
            if (same_direction) throw std::logic_error("procedural body: the cage is not orientable");
            continue;
          }
          if (same_direction) std::reverse(mesh.faces[g].begin(), mesh.faces[g].end());
          done[g] = true;
          queue.push(g);
        }
      }
    }
    double volume = 0;
    for (int64_t f : component) {
      const auto& face = mesh.faces[f];
      for (size_t i = 1; i + 1 < face.size(); ++i)
        volume += dot(positions[face[0]], cross(positions[face[i]], positions[face[i + 1]]));
    }
    if (volume < 0)
      for (int64_t f : component) std::reverse(mesh.faces[f].begin(), mesh.faces[f].end());
  }
}

// The vertex at the mirror image of each vertex; the builder makes mirrored positions exact negations of x.
std::vector<int64_t> mirror_by_position(const std::vector<Vec3>& positions) {
  std::map<Vec3, int64_t> index;
  for (size_t i = 0; i < positions.size(); ++i) {
    if (!index.emplace(positions[i], static_cast<int64_t>(i)).second)
      throw std::logic_error("procedural body: two cage vertices coincide");
  }
  std::vector<int64_t> mirror(positions.size());
  for (size_t i = 0; i < positions.size(); ++i) {
    const auto it = index.find(mirrored(positions[i]));
    if (it == index.end()) throw std::logic_error("procedural body: the cage is not symmetric");
    mirror[i] = it->second;
  }
  return mirror;
}

// ---- the cage ---------------------------------------------------------------------------------------------------

// A UV chart: a cylinder (u around `axis`, seam on the -e1 side; v along the axis) or a plane (u, v along e1, e2).
struct Chart {
  bool cylinder;
  Vec3 origin, axis, e1, e2;
};

// Side +1 is the subject's left (x > 0); side -1 builds the mirror image from the same left-side numbers, so the
// two halves agree to the last bit. Joints are given as the left side's and mirrored with the geometry.
class Cage {
 public:
  int64_t add(int side, const Vec3& left_position, const JointWeights& left_weights) {
    positions_.push_back(side > 0 ? left_position : mirrored(left_position));
    JointWeights w = left_weights;
    if (side < 0)
      for (auto& entry : w) entry.first = kSmplxMirroredJoints[entry.first];
    weights_.push_back(w);
    return static_cast<int64_t>(positions_.size()) - 1;
  }
  int64_t add_midline(const Vec3& position, const JointWeights& weights) {
    return add(1, {0.0, position[1], position[2]}, weights);
  }
  void face(const std::vector<int64_t>& loop, int64_t chart) {
    mesh_.faces.push_back(loop);
    mesh_.charts.push_back(chart);
  }
  // Quads between two closed rings of equal length, skipping those that touch a missing (-1) vertex or whose
  // interval is listed in `skipped` (interval i joins slots i and i + 1).
  void bridge(const std::vector<int64_t>& a, const std::vector<int64_t>& b, int64_t chart,
              const std::vector<size_t>& skipped = {}) {
    for (size_t i = 0; i < a.size(); ++i) {
      const size_t j = (i + 1) % a.size();
      if (a[i] < 0 || a[j] < 0 || b[i] < 0 || b[j] < 0) continue;
      if (std::find(skipped.begin(), skipped.end(), i) != skipped.end()) continue;
      face({a[i], a[j], b[j], b[i]}, chart);
    }
  }
  int64_t chart(int side, Chart c) {
    if (side < 0) {
      c.origin = mirrored(c.origin);
      c.axis = mirrored(c.axis);
      c.e1 = mirrored(c.e1);
      c.e2 = mirrored(c.e2);
    }
    charts_.push_back(c);
    return static_cast<int64_t>(charts_.size()) - 1;
  }
  const Vec3& position(int64_t i) const { return positions_[i]; }
  const std::vector<Vec3>& positions() const { return positions_; }
  const std::vector<JointWeights>& weights() const { return weights_; }
  const std::vector<Chart>& charts() const { return charts_; }
  PolyMesh& mesh() { return mesh_; }

 private:
  std::vector<Vec3> positions_;
  std::vector<JointWeights> weights_;
  std::vector<Chart> charts_;
  PolyMesh mesh_;
};

// Maps a left-side joint to the joint on `side`.
int64_t joint(int side, int64_t left_joint) { return side > 0 ? left_joint : kSmplxMirroredJoints[left_joint]; }

// Finger f of the left hand in SMPL-X order (0 index, 1 middle, 2 pinky, 3 ring, 4 thumb), segment k = 0..2.
int64_t left_finger(int64_t f, int64_t k) { return J::kLeftHandFirst + 3 * f + k; }
constexpr int64_t kIndex = 0, kMiddle = 1, kPinky = 2, kRing = 3, kThumb = 4;

// Vertices of the trunk, neck and head rings: the front (slot 0) and back (slot 8) lie on x = 0, slots 1..7 run
// down the left side from front to back, slot 16 - s mirrors slot s.
constexpr size_t kRingSize = 16;
constexpr size_t kRingBack = 8;
size_t mirrored_slot(size_t slot) { return (kRingSize - slot) % kRingSize; }
size_t slot_on(int side, size_t left_slot) { return side > 0 ? left_slot : mirrored_slot(left_slot); }

// The cage vertex sets whose centroids define each joint (the rows of the joint regressor).
using RegressorSets = std::array<std::vector<int64_t>, kSmplxJointCount>;

struct CageBuild {
  Cage cage;
  RegressorSets regressor;
  std::vector<int64_t> mouth_corners, brows, cheeks;  // left, right cage vertices for the expression directions
  int64_t upper_lip = -1;
  Vec3 head_centre;
};

struct RingShape {
  double h_front, h_back, half_width, depth_front, depth_back, z_centre;
};

Vec3 ring_point(const RingShape& r, double angle_degrees) {
  const double s = std::sin(radians(angle_degrees)), c = std::cos(radians(angle_degrees));
  const double front = std::pow(0.5 * (1.0 + s), 2.0);
  const double h = r.h_back + (r.h_front - r.h_back) * front;
  return at_height(std::abs(angle_degrees) == 90.0 ? 0.0 : r.half_width * c, h,
                   r.z_centre + (s > 0 ? r.depth_front : r.depth_back) * s);
}

// A symmetric ring; `left_point(slot)` and `left_weights(slot, point)` describe slots 0..8 on the left side,
// `missing` lists left slots (1..7) left out on both sides.
std::vector<int64_t> symmetric_ring(Cage& cage, const std::function<Vec3(size_t)>& left_point,
                                    const std::function<JointWeights(size_t, const Vec3&)>& left_weights,
                                    const std::vector<size_t>& missing = {}) {
  std::vector<int64_t> ring(kRingSize, -1);
  for (size_t slot = 0; slot <= kRingBack; ++slot) {
    if (std::find(missing.begin(), missing.end(), slot) != missing.end()) continue;
    const Vec3 p = left_point(slot);
    const JointWeights w = left_weights(slot, p);
    if (slot == 0 || slot == kRingBack) {
      ring[slot] = cage.add_midline(p, w);
    } else {
      ring[slot] = cage.add(1, p, w);
      ring[mirrored_slot(slot)] = cage.add(-1, p, w);
    }
  }
  return ring;
}

// Linear ramp from 0 at `from` to 1 at `to`, clamped.
double ramp(double x, double from, double to) { return std::clamp((x - from) / (to - from), 0.0, 1.0); }

// ---- trunk, neck, head --------------------------------------------------------------------------------------------

constexpr std::array<double, 9> kTrunkAngles = {90, 62, 35, 15, 0, -15, -35, -62, -90};
constexpr std::array<double, 9> kHeadAngles = {90, 73, 50, 25, 0, -25, -50, -73, -90};
constexpr double kArmHeight = 1.405;  // the arms' axis, above the floor
constexpr double kMouthHeight = 1.547;

struct TrunkRing {
  RingShape shape;
  std::function<JointWeights(double lateral)> weights;  // lateral: 0 at the midline .. 1 at the side
};

std::vector<std::vector<int64_t>> build_trunk(CageBuild& b, int64_t chart) {
  using W = JointWeights;
  const std::vector<TrunkRing> rings = {
      {{0.80, 0.80, 0.158, 0.092, 0.105, 0.0},
       [](double l) {
         return W{{J::kPelvis, 1 - 0.45 * l}, {J::kLeftHip, 0.45 * l}};
       }},
      {{0.90, 0.90, 0.168, 0.100, 0.112, -0.005},
       [](double) {
         return W{{J::kPelvis, 1}};
       }},
      {{1.00, 1.00, 0.143, 0.092, 0.092, 0.0},
       [](double) {
         return W{{J::kPelvis, 0.35}, {J::kSpine1, 0.65}};
       }},
      {{1.11, 1.11, 0.150, 0.102, 0.094, 0.005},
       [](double) {
         return W{{J::kSpine1, 0.45}, {J::kSpine2, 0.55}};
       }},
      {{1.23, 1.23, 0.163, 0.112, 0.098, 0.010},
       [](double) {
         return W{{J::kSpine2, 0.45}, {J::kSpine3, 0.55}};
       }},
      {{1.335, 1.335, 0.172, 0.104, 0.094, 0.0},
       [](double l) {
         return W{{J::kSpine3, 1 - 0.35 * l}, {J::kLeftCollar, 0.35 * l}};
       }},
      {{kArmHeight, kArmHeight, 0.184, 0.090, 0.086, 0.0},
       [](double l) {
         return W{{J::kSpine3, 1 - 0.6 * l}, {J::kLeftCollar, 0.6 * l}};
       }},
      {{1.468, 1.468, 0.168, 0.074, 0.074, 0.0},
       [](double l) {
         return W{{J::kSpine3, 0.6 - 0.35 * l}, {J::kNeck, 0.4 * (1 - l)}, {J::kLeftCollar, 0.75 * l}};
       }},
      {{1.497, 1.497, 0.066, 0.058, 0.058, -0.005},
       [](double) {
         return W{{J::kSpine3, 0.25}, {J::kNeck, 0.75}};
       }},
      {{1.550, 1.550, 0.055, 0.055, 0.057, -0.010},
       [](double) {
         return W{{J::kNeck, 0.5}, {J::kHead, 0.5}};
       }},
  };
  std::vector<std::vector<int64_t>> built;
  for (size_t r = 0; r < rings.size(); ++r) {
    // The middle shoulder ring leaves out three side vertices: the arm holes.
    const std::vector<size_t> missing = r == 6 ? std::vector<size_t>{3, 4, 5} : std::vector<size_t>{};
    built.push_back(symmetric_ring(
        b.cage, [&](size_t slot) { return ring_point(rings[r].shape, kTrunkAngles[slot]); },
        [&](size_t, const Vec3& p) { return rings[r].weights(ramp(p[0], 0.07, 0.16)); }, missing));
    if (r > 0) b.cage.bridge(built[r - 1], built[r], chart);
  }
  b.regressor[J::kPelvis] = built[1];
  b.regressor[J::kSpine1] = built[2];
  b.regressor[J::kSpine2] = built[3];
  b.regressor[J::kSpine3] = built[4];
  b.regressor[J::kNeck] = built[8];
  b.regressor[J::kHead] = built[9];
  for (int side : {1, -1}) {
    b.regressor[joint(side, J::kLeftCollar)] = {built[7][slot_on(side, 1)], built[7][slot_on(side, 7)],
                                                built[8][slot_on(side, 4)]};
  }
  return built;
}

void build_head(CageBuild& b, const std::vector<int64_t>& neck, int64_t head_chart, int64_t top_chart,
                int64_t mouth_chart) {
  using W = JointWeights;
  const std::vector<RingShape> shapes = {
      {1.507, 1.585, 0.060, 0.066, 0.060, 0.012}, {1.541, 1.600, 0.067, 0.082, 0.076, 0.012},
      {1.547, 1.615, 0.071, 0.078, 0.085, 0.012}, {1.553, 1.630, 0.074, 0.088, 0.090, 0.012},
      {1.588, 1.650, 0.076, 0.093, 0.095, 0.012}, {1.627, 1.670, 0.078, 0.087, 0.098, 0.012},
      {1.660, 1.695, 0.078, 0.093, 0.098, 0.012}, {1.703, 1.725, 0.073, 0.087, 0.092, 0.012},
      {1.738, 1.750, 0.055, 0.063, 0.068, 0.012}, {1.758, 1.762, 0.026, 0.030, 0.032, 0.012}};
  // Jaw share per left slot of the chin ring, lower lip ring and mouth-corner ring; the rest follows the head.
  const std::array<std::array<double, 9>, 3> jaw_share = {{{1.0, 0.9, 0.7, 0.4, 0.15, 0, 0, 0, 0},
                                                           {1.0, 0.9, 0.5, 0.2, 0.05, 0, 0, 0, 0},
                                                           {0.0, 0.5, 0.25, 0.1, 0, 0, 0, 0, 0}}};
  const double z_centre = 0.012;
  const double lip_depth = z_centre + 0.086;
  const auto point = [&](size_t r, size_t slot) {
    Vec3 p = ring_point(shapes[r], kHeadAngles[slot]);
    const double y_mouth = kMouthHeight + kFloorY;
    if ((r == 1 || r == 3) && slot <= 1) {  // lips: a closed slit
      const double sign = r == 1 ? -1.0 : 1.0;
      p[1] = y_mouth + sign * (slot == 0 ? 0.002 : 0.001);
      p[2] = slot == 0 ? lip_depth : z_centre + 0.079;
    }
    if (r == 2 && slot == 1) p = {0.024, y_mouth, z_centre + 0.074};  // mouth corner
    if (r == 4 && slot == 0) p[2] += 0.028;                           // nose tip
    if (r == 4 && slot == 1) p[2] += 0.006;
    if (r == 5 && slot == 0) p[2] += 0.010;                 // bridge of the nose
    if (r == 5 && (slot == 1 || slot == 2)) p[2] -= 0.012;  // eye sockets
    if ((r == 4 || r == 5) && slot == 4) p[0] += 0.012;     // ears
    return p;
  };
  const auto weights = [&](size_t r, size_t slot) {
    const double jaw = r < 3 ? jaw_share[r][slot] : 0.0;
    if (r == 0 && slot >= 5) return W{{J::kHead, 0.7}, {J::kNeck, 0.3}};
    return W{{J::kHead, 1 - jaw}, {J::kJaw, jaw}};
  };
  std::vector<std::vector<int64_t>> rings;
  for (size_t r = 0; r < shapes.size(); ++r) {
    // The mouth-corner ring has no front vertex: the mouth opens there.
    const std::vector<size_t> missing = r == 2 ? std::vector<size_t>{0} : std::vector<size_t>{};
    rings.push_back(symmetric_ring(
        b.cage, [&](size_t slot) { return point(r, slot); }, [&](size_t slot, const Vec3&) { return weights(r, slot); },
        missing));
    b.cage.bridge(r == 0 ? neck : rings[r - 1], rings[r], head_chart);
  }
  b.cage.face(rings.back(), top_chart);
  b.regressor[J::kJaw] = {rings[2][4], rings[2][mirrored_slot(4)]};
  b.mouth_corners = {rings[2][1], rings[2][mirrored_slot(1)]};
  b.brows = {rings[6][2], rings[6][mirrored_slot(2)]};
  b.cheeks = {rings[3][3], rings[3][mirrored_slot(3)]};
  b.upper_lip = rings[3][0];
  b.head_centre = at_height(0.0, 1.64, z_centre);

  // The mouth: the hole's rim leads into a bag, upper half on the head, lower half on the jaw.
  const std::vector<int64_t> rim = {rings[3][15], rings[3][0], rings[3][1],  rings[2][1],
                                    rings[1][1],  rings[1][0], rings[1][15], rings[2][15]};
  std::vector<int64_t> previous = rim;
  const double y_mouth = kMouthHeight + kFloorY;
  for (const auto& [half_width, half_height, depth] :
       {std::array<double, 3>{0.019, 0.001, lip_depth - 0.010}, {0.016, 0.011, lip_depth - 0.036}}) {
    const W upper = {{J::kHead, 1}}, lower = {{J::kJaw, 1}}, corner = {{J::kHead, 0.5}, {J::kJaw, 0.5}};
    const double side = 0.6 * half_width;
    std::vector<int64_t> loop(8);
    loop[1] = b.cage.add_midline({0, y_mouth + half_height, depth}, upper);
    loop[5] = b.cage.add_midline({0, y_mouth - half_height, depth}, lower);
    for (int s : {1, -1}) {
      loop[s > 0 ? 2 : 0] = b.cage.add(s, {side, y_mouth + 0.9 * half_height, depth}, upper);
      loop[s > 0 ? 3 : 7] = b.cage.add(s, {half_width, y_mouth, depth + 0.002}, corner);
      loop[s > 0 ? 4 : 6] = b.cage.add(s, {side, y_mouth - 0.9 * half_height, depth}, lower);
    }
    b.cage.bridge(previous, loop, mouth_chart);
    previous = loop;
  }
  b.cage.face(previous, mouth_chart);
}

// ---- limbs ----------------------------------------------------------------------------------------------------

// A ring of `count` vertices around an axis point: offsets (a, b) along the frame vectors (ea, eb).
std::vector<int64_t> frame_ring(Cage& cage, int side, const Vec3& centre, const Vec3& ea, const Vec3& eb,
                                const std::vector<std::array<double, 2>>& offsets, const JointWeights& w) {
  std::vector<int64_t> ring;
  for (const auto& [a, b] : offsets) ring.push_back(cage.add(side, centre + a * ea + b * eb, w));
  return ring;
}

std::vector<std::array<double, 2>> ellipse(const std::vector<double>& angles_degrees, double ra, double rb) {
  std::vector<std::array<double, 2>> offsets;
  for (double a : angles_degrees) offsets.push_back({ra * std::cos(radians(a)), rb * std::sin(radians(a))});
  return offsets;
}

Vec3 centroid(const Cage& cage, const std::vector<int64_t>& ids) {
  Vec3 c = {0, 0, 0};
  for (int64_t i : ids) c = c + cage.position(i);
  return (1.0 / static_cast<double>(ids.size())) * c;
}

// The centroid of vertices on `side`, in left-side coordinates.
Vec3 left_centroid(const Cage& cage, int side, const std::vector<int64_t>& ids) {
  Vec3 c = centroid(cage, ids);
  return side > 0 ? c : mirrored(c);
}

void build_leg(CageBuild& b, int side, const std::vector<int64_t>& bottom, int64_t crotch) {
  using W = JointWeights;
  Cage& cage = b.cage;
  const int64_t leg_chart = cage.chart(side, {true, {0.088, 0, 0}, {0, 1, 0}, {1, 0, 0}, {0, 0, 1}});
  const int64_t sole_chart = cage.chart(side, {false, {0.088, 0, 0}, {0, 0, 0}, {1, 0, 0}, {0, 0, 1}});
  const int64_t foot_chart = cage.chart(side, {true, at_height(0.092, 0.03, 0), {0, 0, 1}, {0, 1, 0}, {1, 0, 0}});
  const int64_t toe_chart = cage.chart(side, {false, {0.092, 0, 0.2}, {0, 0, 0}, {1, 0, 0}, {0, 1, 0}});
  // The top loop: the trunk's bottom ring from front to back on this side, then the crotch.
  std::vector<int64_t> loop;
  for (size_t slot = 0; slot <= kRingBack; ++slot) loop.push_back(bottom[slot_on(side, slot)]);
  loop.push_back(crotch);
  b.regressor[joint(side, J::kLeftHip)] = loop;
  const std::vector<double> angles = {144, 108, 72, 36, 0, -36, -72, -108, -144, 180};
  struct LegRing {
    double h, rx, rz, z;
    W w;
  };
  const std::vector<LegRing> rings = {{0.735, 0.080, 0.082, 0.0, {{J::kLeftHip, 0.8}, {J::kPelvis, 0.2}}},
                                      {0.62, 0.071, 0.074, 0.0, {{J::kLeftHip, 1}}},
                                      {0.48, 0.052, 0.056, 0.005, {{J::kLeftHip, 0.5}, {J::kLeftKnee, 0.5}}},
                                      {0.375, 0.052, 0.058, -0.005, {{J::kLeftKnee, 1}}},
                                      {0.22, 0.040, 0.044, 0.0, {{J::kLeftKnee, 1}}},
                                      {0.09, 0.033, 0.037, 0.0, {{J::kLeftKnee, 0.4}, {J::kLeftAnkle, 0.6}}},
                                      {0.012, 0.034, 0.046, -0.012, {{J::kLeftAnkle, 1}}}};
  std::vector<int64_t> previous = loop;
  std::vector<std::vector<int64_t>> built;
  for (size_t r = 0; r < rings.size(); ++r) {
    const LegRing& ring = rings[r];
    built.push_back(frame_ring(cage, side, at_height(0.088, ring.h, ring.z), {1, 0, 0}, {0, 0, 1},
                               ellipse(angles, ring.rx, ring.rz), ring.w));
    // The foot leaves from the front of the lowest segment (intervals 0..2 of the ankle-to-heel bridge).
    cage.bridge(previous, built.back(), leg_chart,
                r == rings.size() - 1 ? std::vector<size_t>{0, 1, 2} : std::vector<size_t>{});
    previous = built.back();
  }
  const std::vector<int64_t>& ankle = built[5];
  const std::vector<int64_t>& heel = built[6];
  cage.face(heel, sole_chart);
  b.regressor[joint(side, J::kLeftKnee)] = built[2];
  b.regressor[joint(side, J::kLeftAnkle)] = ankle;

  std::vector<int64_t> foot = {ankle[0], ankle[1], ankle[2], ankle[3], heel[3], heel[2], heel[1], heel[0]};
  struct FootRing {
    double z, half_width, top, bottom;
    W w;
  };
  const std::vector<FootRing> foot_rings = {{0.070, 0.040, 0.070, 0.0, {{J::kLeftAnkle, 1}}},
                                            {0.125, 0.046, 0.042, 0.0, {{J::kLeftAnkle, 0.5}, {J::kLeftFoot, 0.5}}},
                                            {0.175, 0.042, 0.030, 0.002, {{J::kLeftFoot, 1}}},
                                            {0.200, 0.030, 0.022, 0.006, {{J::kLeftFoot, 1}}}};
  for (size_t r = 0; r < foot_rings.size(); ++r) {
    const FootRing& f = foot_rings[r];
    const double dome = 0.15 * f.top;
    std::vector<int64_t> ring;
    for (const auto& [x, h] : std::vector<std::array<double, 2>>{{-1, f.top},
                                                                 {-1.0 / 3, f.top + dome},
                                                                 {1.0 / 3, f.top + dome},
                                                                 {1, f.top},
                                                                 {1, f.bottom},
                                                                 {1.0 / 3, f.bottom},
                                                                 {-1.0 / 3, f.bottom},
                                                                 {-1, f.bottom}})
      ring.push_back(cage.add(side, at_height(0.092 + x * f.half_width, h, f.z), f.w));
    cage.bridge(foot, ring, foot_chart);
    if (r == 1) b.regressor[joint(side, J::kLeftFoot)] = ring;
    foot = ring;
  }
  cage.face(foot, toe_chart);
}

// A finger (or thumb) tube from `base` (its loop on the palm) along `direction`; ring k sits at distance
// stations[k] with half width widths[k] and weights segment_weights[k]. The last ring is capped.
void build_digit(CageBuild& b, int side, const std::vector<int64_t>& base, const Vec3& direction,
                 const std::vector<std::array<double, 2>>& profile, const std::vector<double>& stations,
                 const std::vector<double>& widths, const std::vector<JointWeights>& segment_weights,
                 const std::vector<size_t>& joint_rings, const std::vector<int64_t>& joints) {
  Cage& cage = b.cage;
  const Vec3 origin = left_centroid(cage, side, base);
  const Vec3 d = normalized(direction);
  const Vec3 along = normalized(Vec3{1, 0, 0} - dot(Vec3{1, 0, 0}, d) * d);
  const Vec3 up_raw = Vec3{0, 1, 0} - dot(Vec3{0, 1, 0}, d) * d;
  const Vec3 up = normalized(up_raw - dot(up_raw, along) * along);
  // For fingers (direction ~ x) the in-plane side axis is horizontal; for the thumb the "along" axis is.
  const bool finger = std::abs(d[0]) > 0.9;
  const Vec3 ea = finger ? normalized(cross(d, up)) : along;
  const int64_t chart = cage.chart(side, {true, origin, d, finger ? Vec3{0, 1, 0} : up, ea});
  const int64_t tip_chart = cage.chart(side, {false, origin + stations.back() * d, {0, 0, 0}, ea, up});
  std::vector<int64_t> previous = base;
  std::vector<std::vector<int64_t>> rings;
  for (size_t k = 0; k < stations.size(); ++k) {
    std::vector<std::array<double, 2>> offsets;
    for (const auto& [a, u] : profile) offsets.push_back({widths[k] * a, 0.92 * widths[k] * u});
    rings.push_back(frame_ring(cage, side, origin + stations[k] * d, ea, up, offsets, segment_weights[k]));
    cage.bridge(previous, rings.back(), chart);
    previous = rings.back();
  }
  cage.face(previous, tip_chart);
  b.regressor[joint(side, joints[0])] = base;
  for (size_t k = 1; k < joints.size(); ++k) b.regressor[joint(side, joints[k])] = rings[joint_rings[k - 1]];
}

void build_arm(CageBuild& b, int side, const std::vector<std::vector<int64_t>>& trunk) {
  using W = JointWeights;
  Cage& cage = b.cage;
  const int64_t arm_chart = cage.chart(side, {true, at_height(0, kArmHeight, 0), {1, 0, 0}, {0, 1, 0}, {0, 0, 1}});
  const int64_t palm_chart = cage.chart(side, {true, at_height(0, kArmHeight, 0), {1, 0, 0}, {0, 0, 1}, {0, 1, 0}});
  // The hole in the trunk: front of the middle ring, the upper ring front to back, back of the middle ring, the
  // lower ring back to front. Slot i of every arm ring sits at angle 30 i around the arm (0 = front, 90 = up).
  const auto& lower = trunk[5];
  const auto& middle = trunk[6];
  const auto& upper = trunk[7];
  std::vector<int64_t> hole = {middle[slot_on(side, 2)]};
  for (size_t s : {2, 3, 4, 5, 6}) hole.push_back(upper[slot_on(side, s)]);
  hole.push_back(middle[slot_on(side, 6)]);
  for (size_t s : {6, 5, 4, 3, 2}) hole.push_back(lower[slot_on(side, s)]);
  b.regressor[joint(side, J::kLeftShoulder)] = hole;

  std::vector<double> angles;
  for (int i = 0; i < 12; ++i) angles.push_back(30.0 * i);
  struct ArmRing {
    double x, ry, rz;
    W w;
  };
  const std::vector<ArmRing> arm = {{0.212, 0.055, 0.058, {{J::kLeftCollar, 0.3}, {J::kLeftShoulder, 0.7}}},
                                    {0.28, 0.048, 0.050, {{J::kLeftShoulder, 1}}},
                                    {0.36, 0.043, 0.045, {{J::kLeftShoulder, 1}}},
                                    {0.45, 0.037, 0.039, {{J::kLeftShoulder, 0.5}, {J::kLeftElbow, 0.5}}},
                                    {0.53, 0.036, 0.040, {{J::kLeftElbow, 1}}},
                                    {0.61, 0.029, 0.033, {{J::kLeftElbow, 1}}},
                                    {0.683, 0.020, 0.028, {{J::kLeftElbow, 0.4}, {J::kLeftWrist, 0.6}}}};
  std::vector<int64_t> previous = hole;
  for (size_t r = 0; r < arm.size(); ++r) {
    const ArmRing& ring = arm[r];
    const std::vector<int64_t> built = frame_ring(cage, side, at_height(ring.x, kArmHeight, 0), {0, 0, 1}, {0, 1, 0},
                                                  ellipse(angles, ring.rz, ring.ry), ring.w);
    cage.bridge(previous, built, arm_chart);
    if (r == 3) b.regressor[joint(side, J::kLeftElbow)] = built;
    if (r == 6) b.regressor[joint(side, J::kLeftWrist)] = built;
    previous = built;
  }

  // The palm: a flat box, fingers along +x, thumb towards the front (+z), palm facing down.
  const std::vector<std::array<double, 2>> box = {{1, 0},  {0.8, 1},   {0.4, 1},   {0, 1},  {-0.4, 1}, {-0.8, 1},
                                                  {-1, 0}, {-0.8, -1}, {-0.4, -1}, {0, -1}, {0.4, -1}, {0.8, -1}};
  const auto palm_ring = [&](double x, double ry, double rz, const std::vector<W>& w) {
    std::vector<int64_t> ring;
    for (size_t i = 0; i < box.size(); ++i)
      ring.push_back(cage.add(side, at_height(x, kArmHeight + ry * box[i][1], rz * box[i][0]), w[i]));
    return ring;
  };
  const W wrist = {{J::kLeftWrist, 1}};
  const std::vector<int64_t> p1 = palm_ring(0.712, 0.017, 0.038, std::vector<W>(12, wrist));
  const std::vector<int64_t> p2 = palm_ring(0.757, 0.016, 0.044, std::vector<W>(12, wrist));
  const auto knuckle = [](std::vector<std::pair<int64_t, double>> fingers) {
    W w = {{J::kLeftWrist, 0.5}};
    for (const auto& [f, share] : fingers) w.push_back({left_finger(f, 0), share});
    double total = 0;
    for (const auto& entry : w) total += entry.second;
    w[0].second += 1 - total;
    return w;
  };
  const std::vector<int64_t> p3 =
      palm_ring(0.800, 0.012, 0.045,
                {knuckle({{kIndex, 0.25}}), knuckle({{kIndex, 0.5}}), knuckle({{kIndex, 0.25}, {kMiddle, 0.25}}),
                 knuckle({{kMiddle, 0.25}, {kRing, 0.25}}), knuckle({{kRing, 0.25}, {kPinky, 0.25}}),
                 knuckle({{kPinky, 0.5}}), knuckle({{kPinky, 0.25}}), knuckle({{kPinky, 0.5}}),
                 knuckle({{kPinky, 0.25}, {kRing, 0.25}}), knuckle({{kRing, 0.25}, {kMiddle, 0.25}}),
                 knuckle({{kMiddle, 0.25}, {kIndex, 0.25}}), knuckle({{kIndex, 0.5}})});
  cage.bridge(previous, p1, palm_chart);
  cage.bridge(p1, p2, palm_chart, {11, 0});  // the thumb leaves from the front faces of this segment
  cage.bridge(p2, p3, palm_chart);
  cage.face({p3[0], p3[1], p3[11]}, palm_chart);
  cage.face({p3[5], p3[6], p3[7]}, palm_chart);

  struct Finger {
    int64_t id;
    std::array<size_t, 4> base;  // top-front, top-back, bottom-back, bottom-front slots of the knuckle ring
    double splay_degrees;
    std::array<double, 3> lengths;
    double base_width, tip_width;
  };
  const std::vector<Finger> fingers = {{kIndex, {1, 2, 10, 11}, 5.0, {0.044, 0.026, 0.022}, 0.0088, 0.0072},
                                       {kMiddle, {2, 3, 9, 10}, 1.5, {0.048, 0.029, 0.024}, 0.0090, 0.0074},
                                       {kRing, {3, 4, 8, 9}, -2.5, {0.045, 0.027, 0.022}, 0.0084, 0.0070},
                                       {kPinky, {4, 5, 7, 8}, -8.0, {0.035, 0.021, 0.019}, 0.0072, 0.0060}};
  const std::vector<std::array<double, 2>> square = {{1, 1}, {-1, 1}, {-1, -1}, {1, -1}};
  for (const Finger& f : fingers) {
    const double l1 = f.lengths[0], l2 = f.lengths[1], l3 = f.lengths[2];
    const auto w = [&](int64_t k) { return W{{left_finger(f.id, k), 1}}; };
    const auto half = [&](int64_t k) { return W{{left_finger(f.id, k), 0.5}, {left_finger(f.id, k + 1), 0.5}}; };
    const double mid = 0.5 * (f.base_width + f.tip_width);
    build_digit(b, side, {p3[f.base[0]], p3[f.base[1]], p3[f.base[2]], p3[f.base[3]]},
                {std::cos(radians(f.splay_degrees)), 0, std::sin(radians(f.splay_degrees))}, square,
                {0.5 * l1, l1, l1 + l2, l1 + l2 + 0.55 * l3, l1 + l2 + 0.92 * l3},
                {f.base_width, 0.5 * (f.base_width + mid), mid, f.tip_width, 0.7 * f.tip_width},
                {w(0), half(0), half(1), w(2), w(2)}, {1, 2},
                {left_finger(f.id, 0), left_finger(f.id, 1), left_finger(f.id, 2)});
  }
  const auto thumb = [&](int64_t k) { return W{{left_finger(kThumb, k), 1}}; };
  const auto thumb_half = [&](int64_t k) {
    return W{{left_finger(kThumb, k), 0.5}, {left_finger(kThumb, k + 1), 0.5}};
  };
  build_digit(b, side, {p1[1], p2[1], p2[0], p2[11], p1[11], p1[0]}, {0.50, -0.25, 0.83},
              {{-0.7, 1}, {0.7, 1}, {1, 0}, {0.7, -1}, {-0.7, -1}, {-1, 0}}, {0.016, 0.040, 0.070, 0.090, 0.101},
              {0.0115, 0.0105, 0.0095, 0.0085, 0.006}, {thumb(0), thumb_half(0), thumb_half(1), thumb(2), thumb(2)},
              {1, 2}, {left_finger(kThumb, 0), left_finger(kThumb, 1), left_finger(kThumb, 2)});
}

CageBuild build_cage() {
  CageBuild b;
  Cage& cage = b.cage;
  const int64_t trunk_chart = cage.chart(1, {true, {0, 0, 0}, {0, 1, 0}, {0, 0, 1}, {1, 0, 0}});
  const int64_t head_chart = cage.chart(1, {true, at_height(0, 1.64, 0.012), {0, 1, 0}, {0, 0, 1}, {1, 0, 0}});
  const int64_t top_chart = cage.chart(1, {false, {0, 0, 0.012}, {0, 0, 0}, {1, 0, 0}, {0, 0, -1}});
  const int64_t mouth_chart = cage.chart(1, {false, at_height(0, kMouthHeight, 0), {0, 0, 0}, {1, 0, 0}, {0, 1, 0}});
  const auto trunk = build_trunk(b, trunk_chart);
  build_head(b, trunk.back(), head_chart, top_chart, mouth_chart);
  const int64_t crotch =
      cage.add_midline(at_height(0, 0.78, 0.0), {{J::kPelvis, 0.6}, {J::kLeftHip, 0.2}, {J::kRightHip, 0.2}});
  for (int side : {1, -1}) {
    build_leg(b, side, trunk.front(), crotch);
    build_arm(b, side, trunk);
  }
  return b;
}

// ---- from the cage to the model -------------------------------------------------------------------------------

constexpr double kEyeRadius = 0.0115;
constexpr double kEyeHeight = 1.632;
constexpr double kEyeHalfSpacing = 0.033;

at::Tensor positions_tensor(const std::vector<Vec3>& positions) {
  at::Tensor t = at::empty({static_cast<int64_t>(positions.size()), 3}, at::kDouble);
  auto a = t.accessor<double, 2>();
  for (size_t i = 0; i < positions.size(); ++i)
    for (int k = 0; k < 3; ++k) a[i][k] = positions[i][k];
  return t;
}

at::Tensor weights_tensor(const std::vector<JointWeights>& weights) {
  at::Tensor t = at::zeros({static_cast<int64_t>(weights.size()), kSmplxJointCount}, at::kDouble);
  auto a = t.accessor<double, 2>();
  for (size_t i = 0; i < weights.size(); ++i)
    for (const auto& [j, w] : weights[i]) a[i][j] += w;
  return t / t.sum(1, /*keepdim=*/true);
}

// A cage smoothed by two Catmull-Clark steps: positions, weights, the quads (corner 0 a vertex point, corner 2 a
// face point) with their charts, and the mirror map.
struct Smoothed {
  at::Tensor positions, weights;
  PolyMesh quads;
  std::vector<int64_t> mirror;
};

Smoothed smooth(Cage& cage) {
  PolyMesh mesh = cage.mesh();
  mesh.vertex_count = static_cast<int64_t>(cage.positions().size());
  orient_outward(mesh, cage.positions());
  const Subdivided first = catmull_clark(mesh, mirror_by_position(cage.positions()));
  const Subdivided second = catmull_clark(first.mesh, first.mirror);
  Smoothed out;
  out.positions = second.stencil.apply(first.stencil.apply(positions_tensor(cage.positions())));
  const at::Tensor weights = second.stencil.apply(first.stencil.apply(weights_tensor(cage.weights())));
  out.weights = weights / weights.sum(1, /*keepdim=*/true);
  out.quads = second.mesh;
  out.mirror = second.mirror;
  return out;
}

// Two eyeballs: cubes smoothed like the body, then projected onto spheres that sit in the eye sockets of `body`.
Smoothed make_eyes(const at::Tensor& body, std::vector<Chart>& charts) {
  const double y_eye = kEyeHeight + kFloorY;
  const at::Tensor x = body.select(1, 0), y = body.select(1, 1), z = body.select(1, 2);
  const at::Tensor near = ((x - kEyeHalfSpacing).abs() < 0.01) & ((y - y_eye).abs() < 0.01) & (z > 0);
  const double surface = z.masked_select(near).max().item<double>();
  const Vec3 centre = {kEyeHalfSpacing, y_eye, surface - 0.8 * kEyeRadius};
  Cage cage;
  for (int side : {1, -1}) {
    const int64_t chart = cage.chart(side, {true, centre, {0, 1, 0}, {0, 0, 1}, {1, 0, 0}});
    const JointWeights w = {{J::kLeftEye, 1}};
    std::array<int64_t, 8> corner;
    for (int i = 0; i < 8; ++i) {
      const Vec3 offset = {i & 1 ? 1.0 : -1.0, i & 2 ? 1.0 : -1.0, i & 4 ? 1.0 : -1.0};
      corner[i] = cage.add(side, centre + kEyeRadius * offset, w);
    }
    for (const auto& quad : std::vector<std::array<int, 4>>{
             {0, 1, 3, 2}, {4, 6, 7, 5}, {0, 4, 5, 1}, {2, 3, 7, 6}, {0, 2, 6, 4}, {1, 5, 7, 3}})
      cage.face({corner[quad[0]], corner[quad[1]], corner[quad[2]], corner[quad[3]]}, chart);
  }
  charts = cage.charts();
  Smoothed eyes = smooth(cage);
  const at::Tensor side = (eyes.positions.select(1, 0) > 0).to(at::kDouble).unsqueeze(1) * 2 - 1;
  const at::Tensor c = at::tensor(std::vector<double>{centre[0], centre[1], centre[2]}, at::kDouble).unsqueeze(0) *
                       at::cat({side, at::ones_like(side), at::ones_like(side)}, 1);
  const at::Tensor d = eyes.positions - c;
  eyes.positions = c + kEyeRadius * d / d.norm(2, 1, /*keepdim=*/true);
  return eyes;
}

// Per-vertex UVs of every triangle corner, charts shelf-packed into the unit square at one common scale.
void make_uvs(const at::Tensor& positions, const at::Tensor& faces, const std::vector<int64_t>& face_charts,
              const std::vector<Chart>& charts, at::Tensor& uvs, at::Tensor& uv_faces) {
  const auto p = positions.accessor<double, 2>();
  const auto f = faces.accessor<int64_t, 2>();
  const int64_t face_count = faces.size(0);
  const auto point = [&](int64_t i) { return Vec3{p[i][0], p[i][1], p[i][2]}; };
  // Mean distance from the axis of each cylinder chart: turns angles into metres.
  std::vector<double> radius(charts.size(), 0.0), radius_count(charts.size(), 0.0);
  for (int64_t t = 0; t < face_count; ++t) {
    const Chart& c = charts[face_charts[t]];
    if (!c.cylinder) continue;
    for (int k = 0; k < 3; ++k) {
      const Vec3 q = point(f[t][k]) - c.origin;
      const Vec3 radial = q - dot(q, c.axis) * c.axis;
      radius[face_charts[t]] += std::sqrt(dot(radial, radial));
      radius_count[face_charts[t]] += 1;
    }
  }
  for (size_t c = 0; c < charts.size(); ++c) radius[c] /= std::max(radius_count[c], 1.0);

  struct Key {
    int64_t vertex, chart, wrapped, pole_face;
    bool operator<(const Key& o) const {
      return std::tie(vertex, chart, wrapped, pole_face) < std::tie(o.vertex, o.chart, o.wrapped, o.pole_face);
    }
  };
  std::map<Key, int64_t> uv_index;
  std::vector<std::array<double, 2>> uv;
  std::vector<int64_t> uv_chart;
  uv_faces = at::empty({face_count, 3}, at::kLong);
  auto uf = uv_faces.accessor<int64_t, 2>();
  for (int64_t t = 0; t < face_count; ++t) {
    const int64_t chart = face_charts[t];
    const Chart& c = charts[chart];
    std::array<std::array<double, 2>, 3> corner_uv;
    std::array<bool, 3> pole = {false, false, false};
    if (c.cylinder) {
      const auto angle = [&](const Vec3& x) {
        const Vec3 q = x - c.origin;
        const Vec3 radial = q - dot(q, c.axis) * c.axis;
        return std::atan2(dot(radial, c.e2), dot(radial, c.e1));
      };
      const Vec3 middle = (1.0 / 3) * (point(f[t][0]) + point(f[t][1]) + point(f[t][2]));
      std::array<double, 3> theta;
      for (int k = 0; k < 3; ++k) {
        const Vec3 q = point(f[t][k]) - c.origin;
        const Vec3 radial = q - dot(q, c.axis) * c.axis;
        pole[k] = std::sqrt(dot(radial, radial)) < 1e-6 * radius[chart];  // on the axis: the angle is undefined
        theta[k] = pole[k] ? angle(middle) : angle(point(f[t][k]));
        corner_uv[k] = {0, dot(q, c.axis)};
      }
      const bool wraps =
          *std::max_element(theta.begin(), theta.end()) - *std::min_element(theta.begin(), theta.end()) > M_PI;
      for (int k = 0; k < 3; ++k) {
        const bool wrapped = wraps && theta[k] < 0;
        corner_uv[k][0] = (theta[k] + (wrapped ? 2 * M_PI : 0.0)) * radius[chart];
        const Key key{f[t][k], chart, wrapped ? 1 : 0, pole[k] ? t : -1};
        const auto [it, inserted] = uv_index.emplace(key, static_cast<int64_t>(uv.size()));
        if (inserted) {
          uv.push_back(corner_uv[k]);
          uv_chart.push_back(chart);
        }
        uf[t][k] = it->second;
      }
    } else {
      for (int k = 0; k < 3; ++k) {
        const Vec3 q = point(f[t][k]) - c.origin;
        const auto [it, inserted] = uv_index.emplace(Key{f[t][k], chart, 0, -1}, static_cast<int64_t>(uv.size()));
        if (inserted) {
          uv.push_back({dot(q, c.e1), dot(q, c.e2)});
          uv_chart.push_back(chart);
        }
        uf[t][k] = it->second;
      }
    }
  }

  // Shelf packing: charts by decreasing height into rows of a fixed width, one scale for all (equal texel density).
  std::vector<std::array<double, 4>> box(charts.size(), {1e30, 1e30, -1e30, -1e30});
  for (size_t i = 0; i < uv.size(); ++i) {
    auto& b = box[uv_chart[i]];
    b = {std::min(b[0], uv[i][0]), std::min(b[1], uv[i][1]), std::max(b[2], uv[i][0]), std::max(b[3], uv[i][1])};
  }
  double area = 0;
  std::vector<size_t> order;
  for (size_t c = 0; c < charts.size(); ++c) {
    if (box[c][2] < box[c][0]) continue;
    area += (box[c][2] - box[c][0]) * (box[c][3] - box[c][1]);
    order.push_back(c);
  }
  std::sort(order.begin(), order.end(),
            [&](size_t a, size_t b) { return box[a][3] - box[a][1] > box[b][3] - box[b][1]; });
  const double margin = 0.01 * std::sqrt(area), row_width = 1.3 * std::sqrt(area);
  std::vector<std::array<double, 2>> offset(charts.size());
  double x = margin, y = margin, row_height = 0, used_width = 0;
  for (size_t c : order) {
    const double w = box[c][2] - box[c][0], h = box[c][3] - box[c][1];
    if (x + w + margin > row_width && x > margin) {
      x = margin;
      y += row_height + margin;
      row_height = 0;
    }
    offset[c] = {x - box[c][0], y - box[c][1]};
    x += w + margin;
    used_width = std::max(used_width, x);
    row_height = std::max(row_height, h);
  }
  const double scale = 1.0 / std::max(used_width, y + row_height + margin);
  uvs = at::empty({static_cast<int64_t>(uv.size()), 2}, at::kDouble);
  auto u = uvs.accessor<double, 2>();
  for (size_t i = 0; i < uv.size(); ++i) {
    u[i][0] = (uv[i][0] + offset[uv_chart[i]][0]) * scale;
    u[i][1] = (uv[i][1] + offset[uv_chart[i]][1]) * scale;
  }
}

// Orthonormal PCA-style basis of the left hand pose: curl, spread and thumb opposition first, completed by
// Gram-Schmidt; the right hand's is its mirror image (x, -y, -z per joint).
std::array<at::Tensor, 4> hand_pose_space() {
  std::vector<std::vector<double>> seeds(3, std::vector<double>(kHandPoseSize, 0.0));
  const Vec3 thumb_flexion = normalized(Vec3{0.83, 0.0, -0.5});
  for (int64_t j = 0; j < kHandJointCount; ++j) {
    const bool thumb = j >= 12;
    const Vec3 curl = thumb ? thumb_flexion : Vec3{0, 0, -1};
    for (int k = 0; k < 3; ++k) seeds[0][3 * j + k] = curl[k];
  }
  for (const auto& [j, amount] : std::vector<std::pair<int64_t, double>>{{0, -1.0}, {3, -0.3}, {6, 1.0}, {9, 0.3}})
    seeds[1][3 * j + 1] = amount;
  for (const auto& [j, axis] : std::vector<std::pair<int64_t, Vec3>>{{12, {0.4, 0.6, 0.0}}, {13, {0.3, 0.0, -0.3}}})
    for (int k = 0; k < 3; ++k) seeds[2][3 * j + k] = axis[k];
  std::vector<at::Tensor> rows;
  const auto add = [&](at::Tensor r) {
    for (const at::Tensor& q : rows) r = r - (r * q).sum() * q;
    const double n = r.norm().item<double>();
    if (n > 1e-6 && static_cast<int64_t>(rows.size()) < kHandPoseSize) rows.push_back(r / n);
  };
  for (const auto& s : seeds) add(at::tensor(s, at::kDouble));
  const at::Tensor identity = at::eye(kHandPoseSize, at::kDouble);
  for (int64_t i = 0; i < kHandPoseSize; ++i) add(identity[i]);
  const at::Tensor left_components = at::stack(rows);
  // A relaxed hand: every finger joint curled a little.
  const at::Tensor left_mean = 0.15 * at::tensor(seeds[0], at::kDouble);
  const at::Tensor flip = at::tensor(std::vector<double>{1, -1, -1}, at::kDouble).repeat({kHandJointCount});
  return {left_components, left_components * flip, left_mean, left_mean * flip};
}

at::Tensor gaussian(const at::Tensor& p, const at::Tensor& centre, double sigma) {
  return (-(p - centre).pow(2).sum(1, /*keepdim=*/true) / (2 * sigma * sigma)).exp();
}

at::Tensor column_sum(const at::Tensor& weights, const std::vector<int64_t>& joints) {
  return weights.index_select(1, at::tensor(joints, at::kLong)).sum(1, /*keepdim=*/true);
}

at::Tensor vec(double x, double y, double z) { return at::tensor(std::vector<double>{x, y, z}, at::kDouble); }

// Ten shape directions (columns of the v1.1 shape space); docs/body_models.md lists their meaning.
at::Tensor shape_directions(const at::Tensor& p, const at::Tensor& w, const at::Tensor& joints) {
  const at::Tensor x = p.select(1, 0).unsqueeze(1), y = p.select(1, 1).unsqueeze(1), z = p.select(1, 2).unsqueeze(1);
  const at::Tensor h = y - kFloorY, zero = at::zeros_like(x);
  const auto on_x = [&](const at::Tensor& d) { return at::cat({d, zero, zero}, 1); };
  const auto on_y = [&](const at::Tensor& d) { return at::cat({zero, d, zero}, 1); };
  const auto on_z = [&](const at::Tensor& d) { return at::cat({zero, zero, d}, 1); };
  const auto smoothstep = [](const at::Tensor& t) { return t * t * (3 - 2 * t); };
  std::vector<at::Tensor> columns;
  columns.push_back(on_y(0.04 * h));  // 0: height, about +7 cm per unit

  // 1: girth, a push away from each bone weighted by skinning.
  std::vector<int64_t> child(kSmplxJointCount, -1);
  for (int64_t j = 1; j < kSmplxJointCount; ++j)
    if (child[kSmplxParents[j]] < 0) child[kSmplxParents[j]] = j;
  child[J::kPelvis] = J::kSpine1;  // not a hip: the trunk's bone is vertical, and symmetric
  child[J::kSpine3] = J::kNeck;
  child[J::kLeftWrist] = J::kLeftHandFirst + 3;  // middle1
  child[J::kRightWrist] = J::kRightHandFirst + 3;
  child[J::kHead] = child[J::kJaw] = child[J::kLeftEye] = child[J::kRightEye] = -1;
  std::vector<double> girth(kSmplxJointCount, 0.02);
  for (int64_t j : {J::kPelvis, J::kSpine1, J::kSpine2, J::kSpine3}) girth[j] = 0.12;
  for (int64_t j : {J::kLeftHip, J::kRightHip, J::kLeftKnee, J::kRightKnee}) girth[j] = 0.10;
  for (int64_t j :
       {J::kLeftCollar, J::kRightCollar, J::kLeftShoulder, J::kRightShoulder, J::kLeftElbow, J::kRightElbow})
    girth[j] = 0.08;
  for (int64_t j : {J::kLeftAnkle, J::kRightAnkle, J::kLeftFoot, J::kRightFoot, J::kNeck}) girth[j] = 0.05;
  for (int64_t j : {J::kHead, J::kJaw}) girth[j] = 0.03;
  girth[J::kLeftEye] = girth[J::kRightEye] = 0.0;
  at::Tensor girth_push = at::zeros_like(p);
  for (int64_t j = 0; j < kSmplxJointCount; ++j) {
    const at::Tensor a = joints[j];
    at::Tensor nearest = a.unsqueeze(0).expand_as(p);
    if (child[j] >= 0) {
      const at::Tensor bone = joints[child[j]] - a;
      const at::Tensor t = ((p - a) * bone).sum(1, /*keepdim=*/true).div(bone.dot(bone)).clamp(0, 1);
      nearest = a + t * bone;
    }
    girth_push = girth_push + girth[j] * w.select(1, j).unsqueeze(1) * (p - nearest);
  }
  columns.push_back(girth_push);

  const at::Tensor head_group = column_sum(w, {J::kHead, J::kJaw, J::kLeftEye, J::kRightEye});
  const at::Tensor upper = smoothstep(((h - 1.15) / 0.25).clamp(0, 1));
  columns.push_back(on_x(0.03 * (x / 0.04).tanh() * upper * (1 - head_group - column_sum(w, {J::kNeck}))));  // 2
  columns.push_back(on_y(-0.05 * ((0.86 - h) / 0.86).clamp_min(0)));                                         // 3: legs
  columns.push_back(on_x(0.04 * x.sign() * ((x.abs() - 0.2) / 0.5).clamp_min(0)));                           // 4: arms
  columns.push_back(0.08 * head_group * (p - joints[J::kHead]));                                             // 5: head
  at::Tensor hands = at::zeros_like(p), fingers = at::zeros_like(p);
  for (Side side : {Side::kLeft, Side::kRight}) {
    std::vector<int64_t> hand, digits;
    for (int64_t k = 0; k < kManoJointCount; ++k) hand.push_back(smplx_hand_joint(side, k));
    digits.assign(hand.begin() + 1, hand.end());
    const at::Tensor wrist = joints[smplx_hand_joint(side, 0)];
    hands = hands + 0.10 * column_sum(w, hand) * (p - wrist);
    fingers = fingers + on_x(0.12 * column_sum(w, digits) * (x - wrist[0]));
  }
  columns.push_back(hands);    // 6: hand size
  columns.push_back(fingers);  // 7: finger length
  const at::Tensor front = (z / 0.1).clamp(0, 1);
  columns.push_back(on_z(0.035 * (-((h - 1.05) / 0.09).pow(2)).exp() * (-(x / 0.11).pow(2)).exp() * front));  // 8
  columns.push_back(on_z(0.025 * (-((h - 1.25) / 0.07).pow(2)).exp() * (-(x / 0.13).pow(2)).exp() * front));  // 9
  return at::stack(columns, 2);
}

// Ten expression directions (as many as SMPL-X's default num_expression_coeffs); direction k becomes direction
// kMirroredExpressions[k] under mirroring.
constexpr std::array<int64_t, 10> kMirroredExpressions = {0, 1, 3, 2, 4, 5, 6, 7, 9, 8};

at::Tensor expression_directions(const at::Tensor& p, const at::Tensor& w, const CageBuild& b) {
  // Fades from nothing where head and jaw hold half the weight to everything where they hold all of it.
  const at::Tensor t = ((column_sum(w, {J::kHead, J::kJaw}) - 0.5) / 0.5).clamp(0, 1);
  const at::Tensor face = t * t * (3 - 2 * t);
  const at::Tensor jaw = column_sum(w, {J::kJaw});
  const auto at_vertex = [&](int64_t i) { return p[i]; };
  const at::Tensor mouth = vec(0.0, kMouthHeight + kFloorY, p[b.upper_lip][2].item<double>());
  const at::Tensor head = vec(b.head_centre[0], b.head_centre[1], b.head_centre[2]);
  std::array<at::Tensor, 2> smile, pucker, puff, frown, brows;
  for (int s = 0; s < 2; ++s) {
    const double out = s == 0 ? 1.0 : -1.0;  // towards the side of the corner
    const at::Tensor corner = at_vertex(b.mouth_corners[s]);
    smile[s] = 0.006 * vec(0.5 * out, 1.0, -0.5) * gaussian(p, corner, 0.012);
    pucker[s] = 0.004 * vec(-out, 0.0, 0.3) * gaussian(p, corner, 0.010);
    frown[s] = 0.005 * vec(0.0, -1.0, 0.0) * gaussian(p, corner, 0.012);
    brows[s] = 0.006 * vec(0.0, 1.0, 0.0) * gaussian(p, at_vertex(b.brows[s]), 0.015);
    at::Tensor radial = p - head;
    radial.select(1, 1).zero_();
    puff[s] = 0.006 * radial / radial.norm(2, 1, /*keepdim=*/true).clamp_min(1e-9) *
              gaussian(p, at_vertex(b.cheeks[s]), 0.018);
  }
  const std::vector<at::Tensor> columns = {
      face * jaw * vec(0.0, -0.010, -0.002),                                                    // 0: mouth open
      face * (smile[0] + smile[1]),                                                             // 1: smile
      face * smile[0],                                                                          // 2: left smile
      face * smile[1],                                                                          // 3: right smile
      face * (brows[0] + brows[1]),                                                             // 4: brows up
      face * (0.006 * vec(0.0, 0.0, 1.0) * gaussian(p, mouth, 0.014) + pucker[0] + pucker[1]),  // 5: pucker
      face * (puff[0] + puff[1]),                                                               // 6: cheeks puffed
      face * (frown[0] + frown[1]),                                                             // 7: frown
      face * brows[0],                                                                          // 8: left brow up
      face * brows[1]};                                                                         // 9: right brow up
  return at::stack(columns, 2);
}

// The MANO-layout hand of `side`: the body's hand region (and the vertices its joints are regressed from) in the
// body's model space, open at the wrist, with MANO's 16 joints and the body shape space minus the wrist's motion.
ManoModelData cut_hand(const SmplxModelData& body, const at::Tensor& ids, const at::Tensor& faces, Side side,
                       const at::Tensor& components, const at::Tensor& mean) {
  std::vector<int64_t> hand_joints;
  for (int64_t k = 0; k < kManoJointCount; ++k) hand_joints.push_back(smplx_hand_joint(side, k));
  const at::Tensor joints = at::tensor(hand_joints, at::kLong);
  ManoModelData hand;
  hand.source = std::string("procedural ") + (side == Side::kLeft ? "left" : "right") + " hand";
  hand.v_template = body.v_template.index_select(0, ids);
  hand.faces = faces;
  hand.j_regressor = body.j_regressor.index_select(0, joints).index_select(1, ids);
  hand.weights = body.weights.index_select(0, ids).index_select(1, joints);
  hand.weights.select(1, 0).add_(1 - hand.weights.sum(1));  // the forearm's share moves with the wrist
  hand.parents.assign(kManoParents.begin(), kManoParents.end());
  const at::Tensor shape = body.shapedirs.narrow(2, 0, kManoShapeSpace);
  const at::Tensor wrist_motion = at::einsum("v,vck->ck", {body.j_regressor[hand_joints[0]], shape});
  hand.shapedirs = shape.index_select(0, ids) - wrist_motion.unsqueeze(0);
  hand.hands_components = components;
  hand.hands_mean = mean;
  return hand;
}

}  // namespace

ProceduralBody make_procedural_body() {
  CageBuild build = build_cage();
  const Smoothed body = smooth(build.cage);
  std::vector<Chart> eye_charts;
  const Smoothed eyes = make_eyes(body.positions, eye_charts);
  const int64_t body_count = body.positions.size(0);
  const int64_t vertex_count = body_count + eyes.positions.size(0);

  // Triangles: each smoothed quad (vertex point, edge point, face point, edge point) is split between its two edge
  // points, a choice that mirrors onto itself, so the triangulation stays symmetric.
  std::vector<int64_t> triangles, triangle_charts;
  const int64_t body_charts = static_cast<int64_t>(build.cage.charts().size());
  for (const auto& [mesh, vertex_offset, chart_offset] :
       {std::tuple{&body.quads, int64_t{0}, int64_t{0}}, {&eyes.quads, body_count, body_charts}}) {
    for (size_t q = 0; q < mesh->faces.size(); ++q) {
      const auto& c = mesh->faces[q];
      for (const auto& tri : {std::array<int64_t, 3>{c[0], c[1], c[3]}, {c[1], c[2], c[3]}}) {
        for (int64_t corner : tri) triangles.push_back(corner + vertex_offset);
        triangle_charts.push_back(mesh->charts[q] + chart_offset);
      }
    }
  }
  std::vector<Chart> charts = build.cage.charts();
  charts.insert(charts.end(), eye_charts.begin(), eye_charts.end());

  ProceduralBody out;
  SmplxModelData& d = out.smplx;
  d.source = "procedural body";
  d.v_template = at::cat({body.positions, eyes.positions});
  d.faces = at::tensor(triangles, at::kLong).view({-1, 3});
  std::vector<int64_t> mirror = body.mirror;
  for (int64_t m : eyes.mirror) mirror.push_back(m + body_count);
  out.mirrored_vertices = at::tensor(mirror, at::kLong);
  d.weights = at::cat({body.weights, eyes.weights});
  // Catmull-Clark sums mirrored stencils in different orders; averaging each vertex with its mirror image makes the
  // two halves agree to the last bit (IEEE addition commutes), so even ties in argmax-based labels stay symmetric.
  const at::Tensor mirror_index = out.mirrored_vertices;
  const at::Tensor joint_mirror =
      at::tensor(std::vector<int64_t>(kSmplxMirroredJoints.begin(), kSmplxMirroredJoints.end()), at::kLong);
  const at::Tensor flip_x = at::tensor(std::vector<double>{-1, 1, 1}, at::kDouble);
  d.v_template = 0.5 * (d.v_template + d.v_template.index_select(0, mirror_index) * flip_x);
  d.weights = 0.5 * (d.weights + d.weights.index_select(0, mirror_index).index_select(1, joint_mirror));
  for (int64_t i = body_count; i < vertex_count; ++i)
    build.regressor[d.v_template[i][0].item<double>() > 0 ? J::kLeftEye : J::kRightEye].push_back(i);
  d.j_regressor = at::zeros({kSmplxJointCount, vertex_count}, at::kDouble);
  for (int64_t j = 0; j < kSmplxJointCount; ++j) {
    const auto& ids = build.regressor[j];
    if (ids.empty()) throw std::logic_error("procedural body: no regressor for joint " + std::to_string(j));
    d.j_regressor[j].index_fill_(0, at::tensor(ids, at::kLong), 1.0 / static_cast<double>(ids.size()));
  }
  d.parents.assign(kSmplxParents.begin(), kSmplxParents.end());
  const at::Tensor joints = d.j_regressor.matmul(d.v_template);
  d.shapedirs = shape_directions(d.v_template, d.weights, joints);
  d.exprdirs = expression_directions(d.v_template, d.weights, build);
  const auto [left_components, right_components, left_mean, right_mean] = hand_pose_space();
  d.hands_components_left = left_components;
  d.hands_components_right = right_components;
  d.hands_mean_left = left_mean;
  d.hands_mean_right = right_mean;
  make_uvs(d.v_template, d.faces, triangle_charts, charts, d.uvs, d.uv_faces);
  d.part_labels = part_labels_from_weights(d.weights);
  d.validate();
  out.mirrored_expressions.assign(kMirroredExpressions.begin(), kMirroredExpressions.end());
  out.face_vertex_ids = (d.part_labels == static_cast<int64_t>(BodyPart::kFace)).nonzero().flatten();

  // The right hand region, then the left as its mirror image vertex by vertex.
  at::Tensor in_hand = d.part_labels == static_cast<int64_t>(BodyPart::kRightHand);
  for (int64_t k = 0; k < kManoJointCount; ++k)
    in_hand = in_hand | (d.j_regressor[smplx_hand_joint(Side::kRight, k)] > 0);
  const at::Tensor right_ids = in_hand.nonzero().flatten();
  const at::Tensor left_ids = out.mirrored_vertices.index_select(0, right_ids);
  at::Tensor local = at::full({vertex_count}, -1, at::kLong);
  local.index_copy_(0, right_ids, at::arange(right_ids.size(0), at::kLong));
  const at::Tensor corners = local.index_select(0, d.faces.flatten()).view({-1, 3});
  const at::Tensor right_faces = corners.index_select(0, (corners >= 0).all(1).nonzero().flatten());
  const at::Tensor left_faces = right_faces.flip(1).contiguous();
  out.hand_vertex_ids = {left_ids, right_ids};
  out.mano_right = cut_hand(d, right_ids, right_faces, Side::kRight, right_components, right_mean);
  out.mano_left = cut_hand(d, left_ids, left_faces, Side::kLeft, left_components, left_mean);
  out.mano_right.validate();
  out.mano_left.validate();
  return out;
}

void write_procedural_body(const ProceduralBody& body, const std::string& folder, bool overwrite) {
  namespace fs = std::filesystem;
  TORCH_CHECK(fs::is_directory(folder), "write_procedural_body: folder '", folder, "' does not exist");
  const auto path = [&](const char* name) { return (fs::path(folder) / name).string(); };
  body.smplx.save(path("procedural_smplx.npz"), overwrite);
  body.mano_left.save(path("procedural_mano_left.npz"), overwrite);
  body.mano_right.save(path("procedural_mano_right.npz"), overwrite);
  io::write_npz(path("procedural_MANO_SMPLX_vertex_ids.npz"),
                {{"left_hand", body.hand_vertex_ids.left}, {"right_hand", body.hand_vertex_ids.right}}, overwrite);
  io::write_npy(path("procedural_face_vertex_ids.npy"), body.face_vertex_ids, overwrite);
}

}  // namespace sfgs::body
