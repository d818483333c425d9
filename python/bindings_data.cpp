// The module's metrics and dataset reading: sfgs.psnr, sfgs.ssim (three border conventions), sfgs.lpips,
// sfgs.evaluate (a frame as `sfgs eval` scores it) and sfgs.read_dataset (docs/python.md). Every function validates in
// C++ and raises RuntimeError naming what is wrong.
#include <algorithm>
#include <cmath>
#include <map>
#include <mutex>
#include <optional>
#include <string>
#include <utility>

#include "metrics/evaluation.h"
#include "metrics/image_metrics.h"
#include "metrics/lpips.h"
#include "python_values.h"
#include "train/run_folder.h"

namespace sfgs::python {
namespace {

using body::SmplxPose;

metrics::SsimBorder ssim_border(const std::string& name) {
  if (name == "reflect") return metrics::SsimBorder::reflect;
  if (name == "zero") return metrics::SsimBorder::zero;
  if (name == "valid") return metrics::SsimBorder::valid;
  throw py::value_error(
      "ssim(border): expected 'reflect' (torchmetrics >= 1.4.2, the reported number), 'zero' "
      "(the 3DGS training loss) or 'valid' (scikit-image), got '" +
      name + "'");
}

// LPIPS networks are loaded once per weights file and kept.
const metrics::Lpips& lpips_network(const std::string& net, const std::string& directory) {
  static std::mutex guard;
  static std::map<std::string, metrics::Lpips> loaded;
  if (net != "alex" && net != "squeeze")
    throw py::value_error("lpips(net): expected 'alex' or 'squeeze', got '" + net + "'");
  const metrics::LpipsNet which = net == "alex" ? metrics::LpipsNet::alex : metrics::LpipsNet::squeeze;
  const std::string file =
      metrics::lpips_weights_file(which, directory.empty() ? metrics::default_lpips_weights_dir() : directory);
  const std::lock_guard<std::mutex> lock(guard);
  auto found = loaded.find(file);
  if (found == loaded.end()) found = loaded.emplace(file, metrics::Lpips::load(which, file)).first;
  return found->second;
}

class PyDataset {
 public:
  explicit PyDataset(const std::string& folder) : d_(data::read_dataset(folder)) {}
  int64_t size() const { return d_.size(); }
  py::dict frame(const py::object& index_object) const {
    const int64_t index = to_int(index_object, "Dataset.frame(index)");
    py::dict out = frame_record_dict(d_, index);
    const data::Frame f = d_.load(index);
    out["image"] = f.image;
    out["mask"] = f.mask;
    out["eval_mask"] = f.eval_mask;
    return out;
  }
  std::vector<int64_t> split(const std::string& name) const {
    if (name == "train") return d_.split(data::Split::kTrain);
    if (name == "val") return d_.split(data::Split::kVal);
    if (name == "test") return d_.split(data::Split::kTest);
    throw py::value_error("Dataset.split(name): expected 'train', 'val' or 'test', got '" + name + "'");
  }
  const data::Dataset& dataset() const { return d_; }

 private:
  data::Dataset d_;
};

}  // namespace

py::dict frame_record_dict(const data::Dataset& d, int64_t index) {
  TORCH_CHECK(index >= 0 && index < d.size(), "frame: index must be in [0, ", d.size(), "), got ", index);
  const data::FrameRecord& record = d.frames[size_t(index)];
  py::dict pose;
  for (const SmplxPose::Field& f : SmplxPose::fields())
    if ((record.pose.*(f.member)).defined()) pose[f.name] = record.pose.*(f.member);
  const std::optional<double> time = d.replay_time(index);
  pose["time"] = time ? py::object(py::float_(*time)) : py::object(py::none());
  py::dict out;
  out["pose"] = pose;
  out["camera"] = camera_dict(train::render_camera(record));
  out["name"] = record.name;
  const char* names[] = {"train", "val", "test"};
  for (const auto split : {data::Split::kTrain, data::Split::kVal, data::Split::kTest}) {
    const auto& members = d.split(split);
    if (std::find(members.begin(), members.end(), index) != members.end()) out["split"] = names[int(split)];
  }
  return out;
}

namespace {

// How far past [0, 1] an image's values may lie (a blend's rounding) before they are taken for another scale.
constexpr double kImageRangeSlack = 1e-4;

// The metrics score images in [0, 1]: 8-bit values, [-1, 1] images or NaN would give a number that means nothing.
// One reduction and one host read, here at the module's boundary only (the training step's metrics run on the
// device unchecked).
at::Tensor image_in_unit_range(const py::object& object, const std::string& what) {
  const at::Tensor t = to_tensor(object, what);
  if (!t.defined() || !at::isFloatingType(t.scalar_type()) || t.numel() == 0) return t;  // the metric names these
  const auto [low_value, high_value] = at::aminmax(t.detach());
  const at::Tensor bounds = at::stack({low_value, high_value}).to(at::kCPU, at::kDouble);
  const double low = bounds[0].item<double>(), high = bounds[1].item<double>();
  TORCH_CHECK(!std::isnan(low) && !std::isnan(high), what, ": the image holds NaN");  // min and max propagate NaN
  TORCH_CHECK(low >= -kImageRangeSlack && high <= 1 + kImageRangeSlack, what,
              ": values must lie in [0, 1] (float images), got [", low, ", ", high, "]",
              high > 2  ? "; 8-bit images take / 255"
              : low < 0 ? "; [-1, 1] images take (x + 1) / 2"
                        : "");
  return t;
}

}  // namespace

void bind_metrics_and_data(py::module_& m) {
  m.def(
      "psnr",
      [](const py::object& prediction, const py::object& target) {
        return metrics::psnr(image_in_unit_range(prediction, "psnr(prediction)"),
                             image_in_unit_range(target, "psnr(target)"));
      },
      py::arg("prediction"), py::arg("target"),
      "PSNR (dB) of images in [0, 1], (H, W, C) -> 0-dim or (B, H, W, C) -> (B); identical images give inf. "
      "Differentiable.");
  m.def(
      "ssim",
      [](const py::object& prediction, const py::object& target, const std::string& border) {
        return metrics::ssim(image_in_unit_range(prediction, "ssim(prediction)"),
                             image_in_unit_range(target, "ssim(target)"), ssim_border(border));
      },
      py::arg("prediction"), py::arg("target"), py::arg("border") = "reflect",
      "Mean SSIM (11 x 11 Gaussian window, sigma 1.5) of images in [0, 1], channels last; border 'reflect' "
      "(torchmetrics >= 1.4.2, reported), 'zero' (3DGS training loss) or 'valid' (scikit-image). Differentiable.");
  m.def(
      "lpips",
      [](const py::object& prediction, const py::object& target, const std::string& net, const std::string& dir) {
        const at::Tensor p = image_in_unit_range(prediction, "lpips(prediction)");
        const at::Tensor t = image_in_unit_range(target, "lpips(target)");
        return lpips_network(net, dir)(p, t);
      },
      py::arg("prediction"), py::arg("target"), py::arg("net") = "alex", py::arg("weights_dir") = "",
      "LPIPS of RGB images in [0, 1], (H, W, 3) or (B, H, W, 3); weights from weights_dir (default $SFGS_LPIPS_DIR "
      "or ../shared/lpips). Differentiable.");
  m.def(
      "evaluate",
      [](const py::object& prediction, const py::object& image, const py::object& mask, bool eight_bit, bool lpips,
         const std::string& weights_dir) {
        // The render as `sfgs eval` takes it: a shaded render may exceed 1 (the protocol's 8-bit round trip
        // saturates it); only NaN is refused here. The frame's image must be an image in [0, 1].
        const at::Tensor p = to_tensor(prediction, "evaluate(prediction)");
        TORCH_CHECK(!p.defined() || !at::isFloatingType(p.scalar_type()) || !p.isnan().any().item<bool>(),
                    "evaluate(prediction): the image holds NaN");
        const at::Tensor t = image_in_unit_range(image, "evaluate(image)");
        const at::Tensor m = mask.is_none() ? at::Tensor() : to_tensor(mask, "evaluate(mask)");
        metrics::EvaluationOptions options;
        options.eight_bit_round_trip = eight_bit;
        options.composite_on_white = m.defined();
        std::optional<metrics::ImageEvaluator> evaluator;
        if (lpips) {
          evaluator.emplace(options, lpips_network("alex", weights_dir));
        } else {
          options.lpips_weights_dir.clear();
          evaluator.emplace(options);
        }
        const metrics::FrameMetrics frame = evaluator->add_frame(p, t, m);
        py::dict out;
        out["psnr"] = frame.psnr;
        out["ssim"] = frame.ssim;
        out["lpips"] = frame.lpips ? py::object(py::float_(*frame.lpips)) : py::object(py::none());
        return out;
      },
      py::arg("prediction"), py::arg("image"), py::arg("mask") = py::none(), py::kw_only(),
      py::arg("eight_bit") = false, py::arg("lpips") = true, py::arg("weights_dir") = "",
      "One frame scored as `sfgs eval` scores it (docs/metrics.md): prediction and image (H, W, 3), composited on "
      "white outside mask (H, W; None: the whole images), PSNR and SSIM in float64, LPIPS (AlexNet; weights as "
      "sfgs.lpips finds them, lpips=False: None); eight_bit rounds the prediction through 8 bits first (`sfgs eval "
      "--eight-bit`). Returns {'psnr', 'ssim', 'lpips'}. Not differentiable.");
  py::class_<PyDataset>(m, "Dataset", "A dataset folder (sfgs synth, NeuMan, X-Humans layouts; docs/dataset_format.md)")
      .def("__len__", &PyDataset::size)
      .def("frame", &PyDataset::frame, py::arg("index"),
           "Frame `index`: {'image' (H, W, 3), 'mask', 'eval_mask' (H, W), 'pose', 'camera', 'name', 'split'}")
      .def("split", &PyDataset::split, py::arg("name"), "Frame indices of 'train', 'val' or 'test'")
      .def_property_readonly("betas", [](const PyDataset& d) { return d.dataset().betas; })
      .def_property_readonly("format", [](const PyDataset& d) { return d.dataset().format; })
      .def_property_readonly("source", [](const PyDataset& d) { return d.dataset().source; });
  m.def(
      "read_dataset", [](const std::string& folder) { return PyDataset(folder); }, py::arg("folder"),
      "Read a dataset folder; errors name the file and what is wrong");
}

}  // namespace sfgs::python
