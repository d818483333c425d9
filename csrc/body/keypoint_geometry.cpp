#include "body/keypoint_geometry.h"

#include <ATen/ATen.h>

#include <cmath>
#include <functional>
#include <limits>
#include <vector>

#include "body/skeleton.h"

namespace sfgs::body {
namespace {

using Point = std::array<double, 3>;

// The rest mesh on the CPU in float64, its joints and each vertex's dominant joint.
struct RestMesh {
  std::vector<Point> vertices;
  std::vector<Point> joints;
  std::vector<int64_t> dominant;
  at::Tensor faces;  // (F, 3) int64

  explicit RestMesh(const SmplxModelData& model) {
    const at::Tensor v = model.v_template.to(at::kCPU, at::kDouble).contiguous();
    const at::Tensor j = model.j_regressor.to(at::kCPU, at::kDouble).matmul(v).contiguous();
    const at::Tensor d = model.weights.to(at::kCPU, at::kDouble).argmax(1).contiguous();
    const auto copy = [](const at::Tensor& t) {
      std::vector<Point> out(size_t(t.size(0)));
      const double* p = t.data_ptr<double>();
      for (size_t i = 0; i < out.size(); ++i) out[i] = {p[3 * i], p[3 * i + 1], p[3 * i + 2]};
      return out;
    };
    vertices = copy(v);
    joints = copy(j);
    dominant.assign(d.data_ptr<int64_t>(), d.data_ptr<int64_t>() + d.numel());
    faces = model.faces.to(at::kCPU, at::kLong).contiguous();
  }

  // The vertex with the largest score among those `eligible` accepts; -1 when none does.
  int64_t best(const std::function<bool(int64_t)>& eligible, const std::function<double(const Point&)>& score) const {
    int64_t found = -1;
    double top = -std::numeric_limits<double>::infinity();
    for (int64_t i = 0; i < int64_t(vertices.size()); ++i) {
      if (!eligible(i)) continue;
      const double s = score(vertices[size_t(i)]);
      if (s > top) {
        top = s;
        found = i;
      }
    }
    return found;
  }

  bool dominated_by(int64_t vertex, std::initializer_list<int64_t> joint_set) const {
    for (int64_t j : joint_set)
      if (dominant[size_t(vertex)] == j) return true;
    return false;
  }
};

int64_t required(int64_t vertex, const char* what, const SmplxModelData& model) {
  TORCH_CHECK(vertex >= 0, "cannot place the ", what, " keypoint on '", model.source,
              "': no vertex of the rest mesh qualifies (is it an SMPL-X-layout model in a T-pose?)");
  return vertex;
}

// Mean iBUG-68 layout in units of the distance between the eye centres, origin between them, x towards the
// subject's left, y up. Point 0 is the subject's right end of the jaw contour (the image's left for a frontal face).
std::array<std::array<double, 2>, kFaceLandmarkCount> mean_face_layout() {
  std::array<std::array<double, 2>, kFaceLandmarkCount> p{};
  for (int i = 0; i < 17; ++i) {  // jaw contour: half an ellipse from ear height round the chin
    const double angle = M_PI + M_PI * i / 16.0;
    p[size_t(i)] = {0.98 * std::cos(angle), -0.1 + 1.65 * std::sin(angle)};
  }
  const double brow[5][2] = {{-0.85, 0.22}, {-0.7, 0.32}, {-0.52, 0.36}, {-0.34, 0.34}, {-0.16, 0.28}};
  for (int i = 0; i < 5; ++i) {
    p[size_t(17 + i)] = {brow[i][0], brow[i][1]};
    p[size_t(26 - i)] = {-brow[i][0], brow[i][1]};
  }
  for (int i = 0; i < 4; ++i) p[size_t(27 + i)] = {0.0, -0.02 - 0.2 * i};  // bridge down to the tip
  const double nostrils[5][2] = {{-0.2, -0.74}, {-0.1, -0.78}, {0.0, -0.8}, {0.1, -0.78}, {0.2, -0.74}};
  for (int i = 0; i < 5; ++i) p[size_t(31 + i)] = {nostrils[i][0], nostrils[i][1]};
  // Eyes: outer corner, upper lid (2), inner corner, lower lid (2); the subject's right eye first.
  const double eye[6][2] = {{-0.72, 0.0}, {-0.58, 0.07}, {-0.42, 0.07}, {-0.28, 0.0}, {-0.42, -0.06}, {-0.58, -0.06}};
  const int left_eye_order[6] = {3, 2, 1, 0, 5, 4};  // 42 is the left eye's inner corner, 45 its outer one
  for (int i = 0; i < 6; ++i) {
    p[size_t(36 + i)] = {eye[i][0], eye[i][1]};
    p[size_t(42 + i)] = {-eye[left_eye_order[i]][0], eye[left_eye_order[i]][1]};
  }
  const double mouth[20][2] = {{-0.4, -1.1},  {-0.26, -1.0},  {-0.1, -0.96}, {0.0, -0.98},  {0.1, -0.96},
                               {0.26, -1.0},  {0.4, -1.1},    {0.26, -1.22}, {0.1, -1.27},  {0.0, -1.28},
                               {-0.1, -1.27}, {-0.26, -1.22}, {-0.34, -1.1}, {-0.1, -1.06}, {0.0, -1.06},
                               {0.1, -1.06},  {0.34, -1.1},   {0.1, -1.14},  {0.0, -1.14},  {-0.1, -1.14}};
  for (int i = 0; i < 20; ++i) p[size_t(48 + i)] = {mouth[i][0], mouth[i][1]};
  return p;
}

struct RayHit {
  int64_t face = -1;
  Point barycentric{};
};

// The foremost (largest z) triangle accepted by `eligible` whose xy projection holds (x, y).
RayHit cast_along_minus_z(const RestMesh& mesh, double x, double y, const std::function<bool(int64_t)>& eligible) {
  RayHit hit;
  double top = -std::numeric_limits<double>::infinity();
  const int64_t* f = mesh.faces.data_ptr<int64_t>();
  for (int64_t t = 0; t < mesh.faces.size(0); ++t) {
    if (!eligible(t)) continue;
    const Point& a = mesh.vertices[size_t(f[3 * t])];
    const Point& b = mesh.vertices[size_t(f[3 * t + 1])];
    const Point& c = mesh.vertices[size_t(f[3 * t + 2])];
    const double det = (b[1] - c[1]) * (a[0] - c[0]) + (c[0] - b[0]) * (a[1] - c[1]);
    if (std::abs(det) < 1e-18) continue;
    const double wa = ((b[1] - c[1]) * (x - c[0]) + (c[0] - b[0]) * (y - c[1])) / det;
    const double wb = ((c[1] - a[1]) * (x - c[0]) + (a[0] - c[0]) * (y - c[1])) / det;
    const double wc = 1 - wa - wb;
    if (wa < 0 || wb < 0 || wc < 0) continue;
    const double z = wa * a[2] + wb * b[2] + wc * c[2];
    if (z > top) {
      top = z;
      hit.face = t;
      hit.barycentric = {wa, wb, wc};
    }
  }
  return hit;
}

}  // namespace

SurfaceKeypointVertices surface_keypoint_vertices(const SmplxModelData& model) {
  if (model.v_template.size(0) == kOfficialSmplxVertexCount) {
    // smplx/vertex_ids.py of the reference loader, 'smplx'.
    return {9120, 9448, 9929, 6,    616, {5361, 4933, 5058, 5169, 5286}, {8079, 7669, 7794, 7905, 8022}, 5770,
            5780, 8846, 8463, 8474, 8635};
  }
  using namespace smplx_joint;
  const RestMesh mesh(model);
  const Point& left_eye_joint = mesh.joints[kLeftEye];
  const Point& right_eye_joint = mesh.joints[kRightEye];
  const double eye_distance = std::hypot(left_eye_joint[0] - right_eye_joint[0], left_eye_joint[1] - right_eye_joint[1],
                                         left_eye_joint[2] - right_eye_joint[2]);
  TORCH_CHECK(eye_distance > 0, "cannot place keypoints on '", model.source, "': its eye joints coincide");
  const double eye_height = (left_eye_joint[1] + right_eye_joint[1]) / 2;
  const double midline = (left_eye_joint[0] + right_eye_joint[0]) / 2;
  const auto head = [&](int64_t i) { return mesh.dominated_by(i, {kHead, kJaw}); };
  const auto y_of = [&](int64_t i) { return mesh.vertices[size_t(i)][1]; };
  const auto x_of = [&](int64_t i) { return mesh.vertices[size_t(i)][0]; };
  const auto forward = [](const Point& v) { return v[2]; };

  SurfaceKeypointVertices s{};
  s.nose = required(mesh.best(
                        [&](int64_t i) {
                          return head(i) && std::abs(x_of(i) - midline) < 0.5 * eye_distance && y_of(i) <= eye_height &&
                                 y_of(i) >= eye_height - 1.5 * eye_distance;
                        },
                        forward),
                    "nose", model);
  const auto eye = [&](int64_t joint, const Point& centre, const char* what) {
    int64_t v = mesh.best([&](int64_t i) { return mesh.dominated_by(i, {joint}); }, forward);
    if (v < 0)
      v = mesh.best(
          [&](int64_t i) {
            return head(i) && std::abs(x_of(i) - centre[0]) < 0.25 * eye_distance &&
                   std::abs(y_of(i) - centre[1]) < 0.25 * eye_distance;
          },
          forward);
    return required(v, what, model);
  };
  s.left_eye = eye(kLeftEye, left_eye_joint, "left eye");
  s.right_eye = eye(kRightEye, right_eye_joint, "right eye");
  const auto near_eye_height = [&](int64_t i) {
    return head(i) && std::abs(y_of(i) - eye_height) < 0.5 * eye_distance;
  };
  s.left_ear = required(mesh.best(near_eye_height, [](const Point& v) { return v[0]; }), "left ear", model);
  s.right_ear = required(mesh.best(near_eye_height, [](const Point& v) { return -v[0]; }), "right ear", model);

  // Finger order thumb, index, middle, ring, pinky; SMPL-X stores index, middle, pinky, ring, thumb (3 joints each).
  const int64_t smplx_finger_slot[kFingerCount] = {4, 0, 1, 3, 2};
  for (Side side : {Side::kLeft, Side::kRight}) {
    const int64_t first = side == Side::kLeft ? kLeftHandFirst : kRightHandFirst;
    auto& tips = side == Side::kLeft ? s.left_fingertips : s.right_fingertips;
    for (int64_t f = 0; f < kFingerCount; ++f) {
      const int64_t last = first + 3 * smplx_finger_slot[f] + 2, middle = last - 1;
      const Point& a = mesh.joints[size_t(middle)];
      const Point& b = mesh.joints[size_t(last)];
      const Point bone{b[0] - a[0], b[1] - a[1], b[2] - a[2]};
      tips[size_t(f)] =
          required(mesh.best([&](int64_t i) { return mesh.dominated_by(i, {last}); },
                             [&](const Point& v) {
                               return (v[0] - b[0]) * bone[0] + (v[1] - b[1]) * bone[1] + (v[2] - b[2]) * bone[2];
                             }),
                   "fingertip", model);
    }
  }
  for (Side side : {Side::kLeft, Side::kRight}) {
    const int64_t foot = side == Side::kLeft ? kLeftFoot : kRightFoot;
    const int64_t ankle = side == Side::kLeft ? kLeftAnkle : kRightAnkle;
    const double foot_x = mesh.joints[size_t(foot)][0], ankle_y = mesh.joints[size_t(ankle)][1];
    // The inner side of a foot is the one nearer the body's midline.
    const auto inner = [&](int64_t i) { return std::abs(x_of(i)) < std::abs(foot_x); };
    const int64_t big = required(
        mesh.best([&](int64_t i) { return mesh.dominated_by(i, {foot}) && inner(i); }, forward), "big toe", model);
    const int64_t small = required(
        mesh.best([&](int64_t i) { return mesh.dominated_by(i, {foot}) && !inner(i); }, forward), "small toe", model);
    const int64_t heel = required(mesh.best(
                                      [&](int64_t i) {
                                        return mesh.dominated_by(i, {foot, ankle}) && y_of(i) < ankle_y;
                                      },
                                      [](const Point& v) { return -v[2]; }),
                                  "heel", model);
    (side == Side::kLeft ? s.left_big_toe : s.right_big_toe) = big;
    (side == Side::kLeft ? s.left_small_toe : s.right_small_toe) = small;
    (side == Side::kLeft ? s.left_heel : s.right_heel) = heel;
  }
  return s;
}

LandmarkEmbedding place_face_landmarks(const SmplxModelData& model) {
  using namespace smplx_joint;
  const RestMesh mesh(model);
  const Point& left = mesh.joints[kLeftEye];
  const Point& right = mesh.joints[kRightEye];
  const double eye_distance = std::hypot(left[0] - right[0], left[1] - right[1]);
  TORCH_CHECK(eye_distance > 0, "cannot place face landmarks on '", model.source, "': its eye joints coincide");
  const double centre_x = (left[0] + right[0]) / 2, centre_y = (left[1] + right[1]) / 2;
  const int64_t* f = mesh.faces.data_ptr<int64_t>();
  const auto on_head = [&](int64_t t) {
    for (int k = 0; k < 3; ++k)
      if (!mesh.dominated_by(f[3 * t + k], {kHead, kJaw})) return false;
    return true;
  };
  const auto layout = mean_face_layout();
  std::vector<RayHit> hits;
  for (const auto& p : layout) {
    RayHit hit;
    // A contour point beyond the face's outline misses it: pull it towards the centre until it lands.
    for (double shrink = 1.0; hit.face < 0 && shrink > 0.4; shrink *= 0.9)
      hit = cast_along_minus_z(mesh, centre_x + shrink * p[0] * eye_distance, centre_y + shrink * p[1] * eye_distance,
                               on_head);
    TORCH_CHECK(hit.face >= 0, "cannot place face landmarks on '", model.source,
                "': no head triangle lies in front of the eyes (is the face towards +z?)");
    hits.push_back(hit);
  }
  const auto pack = [&](int64_t begin, int64_t count) {
    at::Tensor faces = at::empty({count}, at::kLong), bary = at::empty({count, 3}, at::kDouble);
    for (int64_t i = 0; i < count; ++i) {
      faces[i] = hits[size_t(begin + i)].face;
      for (int64_t k = 0; k < 3; ++k) bary[i][k] = hits[size_t(begin + i)].barycentric[size_t(k)];
    }
    return std::make_pair(faces, bary);
  };
  LandmarkEmbedding e;
  std::tie(e.faces, e.barycentrics) = pack(kFaceContourLandmarks, kStaticFaceLandmarks);
  const auto contour = pack(0, kFaceContourLandmarks);
  e.contour_faces = contour.first.unsqueeze(0);
  e.contour_barycentrics = contour.second.unsqueeze(0);
  return e;
}

}  // namespace sfgs::body
