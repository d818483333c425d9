#pragma once
// The cage of the procedural body: a coarse polygon mesh built by box modelling, with skinning weights per vertex
// and a UV chart per face. Side +1 is the subject's left (x > 0); side -1 builds the mirror image from the same
// left-side numbers, so the two halves agree to the last bit. Joints are given as the left side's and mirrored
// with the geometry.
#include <array>
#include <cstdint>
#include <utility>
#include <vector>

#include "body/procedural/poly_mesh.h"
#include "body/procedural/vec3.h"
#include "body/skeleton.h"

namespace sfgs::body::procedural {

namespace J = smplx_joint;

// (joint, weight) pairs of one vertex; normalised when the cage becomes the model.
using JointWeights = std::vector<std::pair<int64_t, double>>;

// A UV chart: a cylinder (u around `axis`, seam on the -e1 side; v along the axis) or a plane (u, v along e1, e2).
struct Chart {
  bool cylinder;
  Vec3 origin, axis, e1, e2;
};

class Cage {
 public:
  int64_t add(int side, const Vec3& left_position, const JointWeights& left_weights);
  int64_t add_midline(const Vec3& position, const JointWeights& weights);
  void face(const std::vector<int64_t>& loop, int64_t chart);
  // Quads between two closed rings of equal length, skipping those that touch a missing (-1) vertex or whose
  // interval is listed in `skipped` (interval i joins slots i and i + 1).
  void bridge(const std::vector<int64_t>& a, const std::vector<int64_t>& b, int64_t chart,
              const std::vector<size_t>& skipped = {});
  int64_t chart(int side, Chart c);

  const Vec3& position(int64_t i) const { return positions_[i]; }
  const std::vector<Vec3>& positions() const { return positions_; }
  const std::vector<JointWeights>& weights() const { return weights_; }
  const std::vector<Chart>& charts() const { return charts_; }
  const PolyMesh& mesh() const { return mesh_; }

 private:
  std::vector<Vec3> positions_;
  std::vector<JointWeights> weights_;
  std::vector<Chart> charts_;
  PolyMesh mesh_;
};

// Maps a left-side joint to the joint on `side`.
inline int64_t joint(int side, int64_t left_joint) { return side > 0 ? left_joint : kSmplxMirroredJoints[left_joint]; }

// A ring of vertices around an axis point: offsets (a, b) along the frame vectors (ea, eb).
std::vector<int64_t> frame_ring(Cage& cage, int side, const Vec3& centre, const Vec3& ea, const Vec3& eb,
                                const std::vector<std::array<double, 2>>& offsets, const JointWeights& w);

// Offsets (ra cos a, rb sin a) of an ellipse at the given angles, for frame_ring.
std::vector<std::array<double, 2>> ellipse(const std::vector<double>& angles_degrees, double ra, double rb);

// The centroid of vertices on `side`, in left-side coordinates.
Vec3 left_centroid(const Cage& cage, int side, const std::vector<int64_t>& ids);

}  // namespace sfgs::body::procedural
