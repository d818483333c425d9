#include "body/procedural/cage.h"

#include <algorithm>
#include <cmath>

namespace sfgs::body::procedural {

int64_t Cage::add(int side, const Vec3& left_position, const JointWeights& left_weights) {
  positions_.push_back(side > 0 ? left_position : mirrored(left_position));
  JointWeights w = left_weights;
  if (side < 0)
    for (auto& entry : w) entry.first = kSmplxMirroredJoints[entry.first];
  weights_.push_back(w);
  return static_cast<int64_t>(positions_.size()) - 1;
}

int64_t Cage::add_midline(const Vec3& position, const JointWeights& weights) {
  return add(1, {0.0, position[1], position[2]}, weights);
}

void Cage::face(const std::vector<int64_t>& loop, int64_t chart) {
  mesh_.faces.push_back(loop);
  mesh_.charts.push_back(chart);
}

void Cage::bridge(const std::vector<int64_t>& a, const std::vector<int64_t>& b, int64_t chart,
                  const std::vector<size_t>& skipped) {
  for (size_t i = 0; i < a.size(); ++i) {
    const size_t j = (i + 1) % a.size();
    if (a[i] < 0 || a[j] < 0 || b[i] < 0 || b[j] < 0) continue;
    if (std::find(skipped.begin(), skipped.end(), i) != skipped.end()) continue;
    face({a[i], a[j], b[j], b[i]}, chart);
  }
}

int64_t Cage::chart(int side, Chart c) {
  if (side < 0) {
    c.origin = mirrored(c.origin);
    c.axis = mirrored(c.axis);
    c.e1 = mirrored(c.e1);
    c.e2 = mirrored(c.e2);
  }
  charts_.push_back(c);
  return static_cast<int64_t>(charts_.size()) - 1;
}

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

Vec3 left_centroid(const Cage& cage, int side, const std::vector<int64_t>& ids) {
  Vec3 c = {0, 0, 0};
  for (int64_t i : ids) c = c + cage.position(i);
  c = (1.0 / static_cast<double>(ids.size())) * c;
  return side > 0 ? c : mirrored(c);
}

}  // namespace sfgs::body::procedural
