#include "body/smplx_pose.h"

#include <sstream>
#include <vector>

#include <ATen/ATen.h>

#include "body/skeleton.h"

namespace sfgs::body {

const std::array<SmplxPose::Field, 9>& SmplxPose::fields() {
  static const std::array<Field, 9> table = {{{"global_orient", &SmplxPose::global_orient, 1},
                                              {"body_pose", &SmplxPose::body_pose, kSmplxBodyJointCount},
                                              {"jaw_pose", &SmplxPose::jaw_pose, 1},
                                              {"leye_pose", &SmplxPose::leye_pose, 1},
                                              {"reye_pose", &SmplxPose::reye_pose, 1},
                                              {"left_hand_pose", &SmplxPose::left_hand_pose, kHandJointCount},
                                              {"right_hand_pose", &SmplxPose::right_hand_pose, kHandJointCount},
                                              {"expression", &SmplxPose::expression, 0},
                                              {"transl", &SmplxPose::transl, 1}}};
  return table;
}

SmplxPose SmplxPose::zeros(int64_t expression_count) {
  SmplxPose p;
  for (const Field& f : fields())
    p.*(f.member) = f.joints == 0   ? at::zeros({expression_count})
                    : f.joints == 1 ? at::zeros({3})
                                    : at::zeros({f.joints, 3});
  return p;
}

SmplxPose SmplxPose::stack(const std::vector<SmplxPose>& frames) {
  SmplxPose batch;
  if (frames.empty()) return batch;
  for (const Field& f : fields()) {
    const bool defined = (frames[0].*(f.member)).defined();
    std::vector<at::Tensor> parts;
    for (const SmplxPose& p : frames) {
      TORCH_CHECK((p.*(f.member)).defined() == defined, "SmplxPose::stack: '", f.name,
                  "' must be given in every frame or in none");
      if (defined) parts.push_back(p.*(f.member));
    }
    if (defined) batch.*(f.member) = at::stack(parts);
  }
  return batch;
}

SmplxPose SmplxPose::frame(int64_t index) const {
  SmplxPose p;
  for (const Field& f : fields())
    if ((this->*(f.member)).defined()) p.*(f.member) = (this->*(f.member)).select(0, index);
  return p;
}

std::string SmplxPose::layout() const {
  std::ostringstream key;
  for (const Field& f : fields()) {
    const at::Tensor& t = this->*(f.member);
    key << (t.defined() ? t.numel() : -1) << ',';
  }
  return key.str();
}

at::Tensor SmplxPose::packed() const {
  std::vector<at::Tensor> values;
  for (const Field& f : fields()) {
    const at::Tensor& t = this->*(f.member);
    if (t.defined()) values.push_back(t.detach().flatten().to(at::kCPU, at::kFloat));
  }
  return values.empty() ? at::zeros({0}) : at::cat(values);
}

SmplxPose SmplxPose::views_of(const at::Tensor& buffer) const {
  SmplxPose views;
  int64_t offset = 0;
  for (const Field& f : fields()) {
    const at::Tensor& t = this->*(f.member);
    if (!t.defined()) continue;
    views.*(f.member) = buffer.narrow(0, offset, t.numel()).view(t.sizes());
    offset += t.numel();
  }
  TORCH_CHECK(buffer.dim() == 1 && buffer.size(0) == offset, "SmplxPose::views_of: the buffer must hold the ", offset,
              " values of the pose's layout, got ", buffer.sizes());
  return views;
}

SmplxPose SmplxPose::to(const at::TensorOptions& options) const {
  SmplxPose p;
  for (const Field& f : fields())
    if ((this->*(f.member)).defined()) p.*(f.member) = (this->*(f.member)).to(options);
  return p;
}

std::string SmplxPose::non_finite() const {
  std::vector<at::Tensor> on_device;
  for (const Field& f : fields()) {
    const at::Tensor& t = this->*(f.member);
    if (t.defined() && !t.is_cpu() && at::isFloatingType(t.scalar_type())) on_device.push_back(t.detach().flatten());
  }
  const bool device_finite = on_device.empty() || at::cat(on_device).isfinite().all().item<bool>();
  for (const Field& f : fields()) {
    const at::Tensor& t = this->*(f.member);
    if (!t.defined() || !at::isFloatingType(t.scalar_type()) || (!t.is_cpu() && device_finite)) continue;
    const at::Tensor flat = t.detach().flatten().cpu();
    const at::Tensor bad = (~flat.isfinite()).nonzero();
    if (bad.numel() == 0) continue;
    std::ostringstream message;
    message << f.name << " must be finite, got " << flat[bad[0][0].item<int64_t>()].item<double>() << " at index "
            << bad[0][0].item<int64_t>() << " (" << bad.size(0) << " of " << flat.numel() << " values are not finite)";
    return message.str();
  }
  return "";
}

}  // namespace sfgs::body
