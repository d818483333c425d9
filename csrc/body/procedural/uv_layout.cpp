#include "body/procedural/uv_layout.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <map>
#include <tuple>

#include <ATen/Functions.h>

#include "body/constants.h"

namespace sfgs::body::procedural {
namespace {

// Charts are packed with gaps of this fraction of the square root of their total area, in rows this many times
// that square root wide (a roughly square atlas).
constexpr double kChartMarginFraction = 0.01;
constexpr double kRowWidthFactor = 1.3;

Vec3 row_point(const at::TensorAccessor<double, 2>& positions, int64_t i) {
  return {positions[i][0], positions[i][1], positions[i][2]};
}

// The component of `x - c.origin` perpendicular to the chart's axis.
Vec3 radial(const Chart& c, const Vec3& x) {
  const Vec3 q = x - c.origin;
  return q - dot(q, c.axis) * c.axis;
}

// Mean distance from the axis of each cylinder chart: turns angles into metres.
std::vector<double> cylinder_radii(const at::TensorAccessor<double, 2>& p, const at::TensorAccessor<int64_t, 2>& f,
                                   const std::vector<int64_t>& face_charts, const std::vector<Chart>& charts) {
  std::vector<double> radius(charts.size(), 0.0), radius_count(charts.size(), 0.0);
  for (int64_t t = 0; t < f.size(0); ++t) {
    const Chart& c = charts[face_charts[t]];
    if (!c.cylinder) continue;
    for (int k = 0; k < 3; ++k) {
      const Vec3 r = radial(c, row_point(p, f[t][k]));
      radius[face_charts[t]] += std::sqrt(dot(r, r));
      radius_count[face_charts[t]] += 1;
    }
  }
  for (size_t c = 0; c < charts.size(); ++c) radius[c] /= std::max(radius_count[c], 1.0);
  return radius;
}

// UV rows in their charts' own coordinates (metres), before packing. A row is shared by the triangle corners
// with the same key: one vertex in one chart, on one side of a cylinder's seam; a corner on a cylinder's axis
// gets a row of its own triangle.
class ChartUvs {
 public:
  int64_t row(int64_t vertex, int64_t chart, bool wrapped, int64_t pole_face, const std::array<double, 2>& uv) {
    const auto [it, inserted] =
        index_.emplace(Key{vertex, chart, wrapped ? 1 : 0, pole_face}, static_cast<int64_t>(uvs_.size()));
    if (inserted) {
      uvs_.push_back(uv);
      charts_.push_back(chart);
    }
    return it->second;
  }
  const std::vector<std::array<double, 2>>& uvs() const { return uvs_; }
  const std::vector<int64_t>& charts() const { return charts_; }

 private:
  struct Key {
    int64_t vertex, chart, wrapped, pole_face;
    bool operator<(const Key& o) const {
      return std::tie(vertex, chart, wrapped, pole_face) < std::tie(o.vertex, o.chart, o.wrapped, o.pole_face);
    }
  };
  std::map<Key, int64_t> index_;
  std::vector<std::array<double, 2>> uvs_;
  std::vector<int64_t> charts_;
};

// Triangle t on a cylinder chart: u is the angle around the axis times the chart's radius, v the height along
// it. A triangle spanning more than half a turn straddles the seam: its corners below it are taken a turn on.
void unwrap_on_cylinder(const at::TensorAccessor<double, 2>& p, const at::TensorAccessor<int64_t, 2>& f, int64_t t,
                        int64_t chart, const Chart& c, double radius, ChartUvs& uvs,
                        at::TensorAccessor<int64_t, 2>& uv_faces) {
  const auto angle = [&](const Vec3& x) {
    const Vec3 r = radial(c, x);
    return std::atan2(dot(r, c.e2), dot(r, c.e1));
  };
  const Vec3 middle = (1.0 / 3) * (row_point(p, f[t][0]) + row_point(p, f[t][1]) + row_point(p, f[t][2]));
  std::array<std::array<double, 2>, 3> corner_uv;
  std::array<bool, 3> pole = {false, false, false};
  std::array<double, 3> theta;
  for (int k = 0; k < 3; ++k) {
    const Vec3 q = row_point(p, f[t][k]) - c.origin;
    const Vec3 r = q - dot(q, c.axis) * c.axis;
    pole[k] = std::sqrt(dot(r, r)) < kUvPoleRadiusFraction * radius;  // on the axis: the angle is undefined
    theta[k] = pole[k] ? angle(middle) : angle(row_point(p, f[t][k]));
    corner_uv[k] = {0, dot(q, c.axis)};
  }
  const bool wraps =
      *std::max_element(theta.begin(), theta.end()) - *std::min_element(theta.begin(), theta.end()) > M_PI;
  for (int k = 0; k < 3; ++k) {
    const bool wrapped = wraps && theta[k] < 0;
    corner_uv[k][0] = (theta[k] + (wrapped ? 2 * M_PI : 0.0)) * radius;
    uv_faces[t][k] = uvs.row(f[t][k], chart, wrapped, pole[k] ? t : -1, corner_uv[k]);
  }
}

// Triangle t on a plane chart: u, v are the coordinates along e1, e2.
void unwrap_on_plane(const at::TensorAccessor<double, 2>& p, const at::TensorAccessor<int64_t, 2>& f, int64_t t,
                     int64_t chart, const Chart& c, ChartUvs& uvs, at::TensorAccessor<int64_t, 2>& uv_faces) {
  for (int k = 0; k < 3; ++k) {
    const Vec3 q = row_point(p, f[t][k]) - c.origin;
    uv_faces[t][k] = uvs.row(f[t][k], chart, false, -1, {dot(q, c.e1), dot(q, c.e2)});
  }
}

// Shelf packing: charts by decreasing height into rows of a fixed width, one scale for all (equal texel density).
at::Tensor pack_charts(const ChartUvs& chart_uvs, size_t chart_count) {
  const std::vector<std::array<double, 2>>& uv = chart_uvs.uvs();
  const std::vector<int64_t>& uv_chart = chart_uvs.charts();
  constexpr double kInf = std::numeric_limits<double>::infinity();
  std::vector<std::array<double, 4>> box(chart_count, {kInf, kInf, -kInf, -kInf});
  for (size_t i = 0; i < uv.size(); ++i) {
    auto& b = box[uv_chart[i]];
    b = {std::min(b[0], uv[i][0]), std::min(b[1], uv[i][1]), std::max(b[2], uv[i][0]), std::max(b[3], uv[i][1])};
  }
  double area = 0;
  std::vector<size_t> order;
  for (size_t c = 0; c < chart_count; ++c) {
    if (box[c][2] < box[c][0]) continue;  // a chart without triangles
    area += (box[c][2] - box[c][0]) * (box[c][3] - box[c][1]);
    order.push_back(c);
  }
  std::sort(order.begin(), order.end(),
            [&](size_t a, size_t b) { return box[a][3] - box[a][1] > box[b][3] - box[b][1]; });
  const double margin = kChartMarginFraction * std::sqrt(area), row_width = kRowWidthFactor * std::sqrt(area);
  std::vector<std::array<double, 2>> offset(chart_count);
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
  at::Tensor uvs = at::empty({static_cast<int64_t>(uv.size()), 2}, at::kDouble);
  auto u = uvs.accessor<double, 2>();
  for (size_t i = 0; i < uv.size(); ++i) {
    u[i][0] = (uv[i][0] + offset[uv_chart[i]][0]) * scale;
    u[i][1] = (uv[i][1] + offset[uv_chart[i]][1]) * scale;
  }
  return uvs;
}

}  // namespace

UvLayout make_uvs(const at::Tensor& positions, const at::Tensor& faces, const std::vector<int64_t>& face_charts,
                  const std::vector<Chart>& charts) {
  const auto p = positions.accessor<double, 2>();
  const auto f = faces.accessor<int64_t, 2>();
  const std::vector<double> radius = cylinder_radii(p, f, face_charts, charts);
  UvLayout out;
  out.uv_faces = at::empty({faces.size(0), 3}, at::kLong);
  auto uf = out.uv_faces.accessor<int64_t, 2>();
  ChartUvs chart_uvs;
  for (int64_t t = 0; t < faces.size(0); ++t) {
    const int64_t chart = face_charts[t];
    if (charts[chart].cylinder)
      unwrap_on_cylinder(p, f, t, chart, charts[chart], radius[chart], chart_uvs, uf);
    else
      unwrap_on_plane(p, f, t, chart, charts[chart], chart_uvs, uf);
  }
  out.uvs = pack_charts(chart_uvs, charts.size());
  return out;
}

}  // namespace sfgs::body::procedural
