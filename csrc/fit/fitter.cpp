#include "fit/fitter.h"

#include <ATen/ATen.h>
#include <torch/optim/adam.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <map>
#include <nlohmann/json.hpp>

#include "body/skeleton.h"
#include "fit/fit_losses.h"
#include "fit/fit_parameters.h"
#include "fit/keypoint_body.h"
#include "fit/silhouette.h"
#include "fit/constants.h"

namespace sfgs::fit {
namespace {

using body::KeypointGroup;
using Clock = std::chrono::steady_clock;

// What one stage optimises and against which keypoints.
struct StagePlan {
  const char* name;
  int64_t iterations;
  double learning_rate;
  double robust_sigma;  // Geman-McClure scale of the keypoint residuals (share of the person's size)
  bool moves_body, moves_details, silhouette;
  at::Tensor keypoint_weights;  // (133)
};

std::vector<StagePlan> stage_plans(const FitStageLengths& lengths, bool silhouette, const at::TensorOptions& options) {
  at::Tensor torso = at::zeros({body::kWholeBodyKeypointCount}, options);
  for (int64_t k : {0, 1, 2, 3, 4, 5, 6, 11, 12}) torso[k] = 1.0;  // nose, eyes, ears, shoulders, hips
  // The body stage sees each hand's wrist and knuckles, which the wrist's rotation alone places, and the face
  // landmarks lightly, for the head's orientation.
  at::Tensor body = group_weights({{KeypointGroup::kBody, 1.0},
                                   {KeypointGroup::kFeet, kFitFeetWeight},
                                   {KeypointGroup::kFace, kFitBodyStageFaceWeight}},
                                  options);
  for (KeypointGroup hand : {KeypointGroup::kLeftHand, KeypointGroup::kRightHand})
    for (int64_t k : {0, 1, 5, 9, 13, 17}) body[body::keypoint_range(hand).begin + k] = 1.0;
  const at::Tensor all = whole_body_keypoint_weights(options);
  std::vector<StagePlan> plans = {
      {"global", lengths.global, kFitLearningRate, kFitGlobalRobustSigma, false, false, false, torso},
      {"body", lengths.body, kFitLearningRate, kFitRobustSigma, true, false, false, body},
      {"detail", lengths.detail, kFitLearningRate, kFitRobustSigma, true, true, false, all}};
  if (silhouette)
    plans.push_back({"silhouette", lengths.silhouette, kFitSilhouetteLearningRate, kFitSilhouetteRobustSigma, true,
                     true, true, all});
  return plans;
}

// The loss of the current parameters under a stage, with its terms for the log.
struct StageLoss {
  at::Tensor total;
  std::map<std::string, at::Tensor> terms;
};

class Objective {
 public:
  Objective(const KeypointBody& body, const body::WholeBodyKeypointMap& keypoint_map,
            const KeypointObservations& observed, const at::Tensor& triples, const SilhouetteTargets& silhouette,
            int64_t keypoint_support)
      : body_(body),
        map_(keypoint_map),
        observed_(observed),
        triples_(triples),
        silhouette_(silhouette),
        keypoint_support_(keypoint_support) {}

  // `robust_sigma`: the keypoints' Geman-McClure scale at this step.
  StageLoss operator()(const FitParameters& p, const StagePlan& plan, double robust_sigma) const {
    const PosedPoints posed = body_.forward(p.betas, p.expression, p.rotations(), p.translation);
    const at::Tensor keypoints = keypoints_of(posed);
    StageLoss l;
    l.terms["keypoints"] = reprojection_loss(keypoints, observed_, plan.keypoint_weights, robust_sigma).mean();
    l.terms["body_prior"] = kFitBodyPriorWeight * body_pose_prior(p.body_pose).mean();
    l.terms["shape_prior"] = kFitShapePriorWeight * p.betas.square().sum();
    l.terms["temporal"] =
        kFitTemporalWeight * temporal_loss(at::cat({keypoints, posed.joints}, 1), triples_, kFitTemporalSigma);
    if (plan.moves_details) {
      l.terms["hand_prior"] = kFitHandPriorWeight * hand_pose_prior(p.left_hand, p.right_hand);
      l.terms["face_prior"] = kFitExpressionPriorWeight * p.expression.square().sum(1).mean() +
                              kFitJawPriorWeight * p.jaw_pose.square().sum(1).mean();
    }
    if (plan.silhouette) {
      const at::Tensor samples = posed.points.narrow(1, keypoint_support_, posed.points.size(1) - keypoint_support_);
      l.terms["silhouette"] =
          kFitSilhouetteWeight * silhouette_loss(project(samples, observed_.intrinsics), silhouette_,
                                                 observed_.person_size, kFitSilhouetteRobustSigma);
    }
    l.total = at::zeros({}, p.translation.options());
    for (const auto& [name, value] : l.terms) l.total = l.total + value;
    return l;
  }

 private:
  at::Tensor keypoints_of(const PosedPoints& posed) const {
    const at::Tensor neck = posed.joint_rotations.select(1, body::smplx_joint::kNeck);
    const at::Tensor bins = body::contour_bins(neck, map_.contour_bin_count());
    return map_.evaluate(posed.points.narrow(1, 0, keypoint_support_), posed.joints, bins);
  }

  const KeypointBody& body_;
  const body::WholeBodyKeypointMap& map_;
  const KeypointObservations& observed_;
  at::Tensor triples_;
  const SilhouetteTargets& silhouette_;
  int64_t keypoint_support_;
};

// The unknowns a stage moves, with their learning-rate multipliers (per-step sizes differ by unit: radians, metres,
// shape and expression coefficients).
std::vector<std::pair<at::Tensor*, double>> moving(FitParameters& p, const StagePlan& plan, bool fit_betas) {
  std::vector<std::pair<at::Tensor*, double>> m = {{&p.root_correction, 1.0}, {&p.translation, 1.0}};
  if (plan.moves_body) {
    m.push_back({&p.body_pose, 1.0});
    if (fit_betas) m.push_back({&p.betas, kFitCoefficientRateFactor});
  }
  if (plan.moves_details) {
    m.insert(
        m.end(),
        {{&p.left_hand, 1.0}, {&p.right_hand, 1.0}, {&p.jaw_pose, 1.0}, {&p.expression, kFitCoefficientRateFactor}});
  }
  return m;
}

FitStageSummary run_stage(FitParameters& p, const StagePlan& plan, const Objective& objective, bool fit_betas,
                          const FitSettings& settings) {
  const auto start = Clock::now();
  const auto unknowns = moving(p, plan, fit_betas);
  std::vector<torch::optim::OptimizerParamGroup> groups;
  for (const auto& [tensor, factor] : unknowns) {
    *tensor = tensor->detach().requires_grad_(true);
    groups.emplace_back(std::vector<at::Tensor>{*tensor},
                        std::make_unique<torch::optim::AdamOptions>(plan.learning_rate * factor));
  }
  torch::optim::Adam adam(groups, torch::optim::AdamOptions(plan.learning_rate));
  FitStageSummary summary{plan.name, plan.iterations, 0, 0};
  for (int64_t step = 0; step < plan.iterations; ++step) {
    // The step size falls linearly to a share of itself over the stage: large moves first, then settling.
    const double progress = double(step) / double(std::max<int64_t>(plan.iterations - 1, 1));
    const double decay = 1.0 - (1.0 - kFitFinalLearningRateShare) * progress;
    for (size_t g = 0; g < unknowns.size(); ++g)
      static_cast<torch::optim::AdamOptions&>(adam.param_groups()[g].options())
          .lr(plan.learning_rate * unknowns[g].second * decay);
    // The robust scale anneals from nearly quadratic (every detection pulls, however far: limbs start far from
    // theirs) down to the stage's scale over the first part of the stage, after which outliers stop pulling.
    const double anneal = std::min(1.0, progress / kFitRobustAnnealShare);
    const double sigma = kFitInitialRobustSigma * std::pow(plan.robust_sigma / kFitInitialRobustSigma, anneal);
    adam.zero_grad();
    const StageLoss loss = objective(p, plan, sigma);
    loss.total.backward();
    adam.step();
    const bool last = step + 1 == plan.iterations;
    if (settings.log_every > 0 && (step % settings.log_every == 0 || last)) {
      const double seconds = std::chrono::duration<double>(Clock::now() - start).count();
      nlohmann::json line{{"stage", plan.name},
                          {"step", step + 1},
                          {"of", plan.iterations},
                          {"loss", loss.total.item<double>()},
                          {"seconds", seconds}};
      std::string text;
      for (const auto& [name, value] : loss.terms) {
        line["terms"][name] = value.item<double>();
        char part[64];
        std::snprintf(part, sizeof(part), " %s %.3g", name.c_str(), value.item<double>());
        text += part;
      }
      if (settings.log) settings.log(line);
      char head[128], tail[32];
      std::snprintf(head, sizeof(head), "sfgs fit: %-10s %4lld/%lld  loss %.4g (", plan.name,
                    static_cast<long long>(step + 1), static_cast<long long>(plan.iterations),
                    loss.total.item<double>());
      std::snprintf(tail, sizeof(tail), ")  %.1f s", seconds);
      if (settings.progress) settings.progress(head + text.substr(1) + tail);
    }
    if (last) summary.loss = loss.total.item<double>();
  }
  for (const auto& [tensor, factor] : unknowns) *tensor = tensor->detach();
  summary.seconds = std::chrono::duration<double>(Clock::now() - start).count();
  if (settings.log)
    settings.log(nlohmann::json{{"stage", plan.name},
                                {"finished", true},
                                {"iterations", summary.iterations},
                                {"seconds", summary.seconds},
                                {"loss", summary.loss}});
  return summary;
}

}  // namespace

FitResult fit_smplx(const body::SmplxModelData& model, const body::WholeBodyKeypointMap& keypoint_map,
                    const FitInput& input, c10::Device device, const FitSettings& settings) {
  TORCH_CHECK(!input.frames.empty(), "sfgs fit: no frame to fit");
  const auto options = at::TensorOptions().dtype(at::kFloat).device(device);
  const int64_t betas = std::min<int64_t>(kFitBetas, model.shapedirs.size(2));
  const int64_t expressions = std::min<int64_t>(kFitExpressions, model.exprdirs.size(2));
  const body::WholeBodyKeypointMap map = keypoint_map.to(device, at::kFloat);

  at::Tensor intrinsics = at::empty({int64_t(input.frames.size()), 4}, at::kDouble);
  std::vector<int64_t> numbers;
  for (size_t i = 0; i < input.frames.size(); ++i) {
    const FitFrame& f = input.frames[i];
    intrinsics[int64_t(i)] = at::tensor({f.fx, f.fy, f.cx, f.cy}, at::kDouble);
    numbers.push_back(f.number);
  }
  const KeypointObservations observed = observe_keypoints(input.keypoints.to(options), intrinsics.to(options));
  const SilhouetteTargets silhouette = settings.use_masks && settings.iterations.silhouette > 0
                                           ? silhouette_targets(input, options)
                                           : SilhouetteTargets{};
  const bool use_silhouette = silhouette.outside_distance.defined();

  const at::Tensor support = keypoint_map.support_vertices();
  const at::Tensor points =
      use_silhouette ? at::cat({support, silhouette_vertex_sample(model, kFitSilhouetteVertices)}) : support;
  const KeypointBody body(model, points, betas, expressions, options);
  at::Tensor start_betas = at::zeros({betas}, at::kFloat);
  const bool fit_betas = !settings.known_betas.defined();
  const at::Tensor given_betas = fit_betas ? settings.initial_betas : settings.known_betas;
  if (given_betas.defined()) {
    const int64_t given = std::min<int64_t>(betas, given_betas.size(0));
    start_betas.narrow(0, 0, given).copy_(given_betas.narrow(0, 0, given));
  }
  FitParameters p = settings.initial_fits
                        ? parameters_from_fits(*settings.initial_fits, start_betas, model.hands_mean_left,
                                               model.hands_mean_right, expressions, options)
                        : initial_parameters(body, map, observed, start_betas, model.hands_mean_left,
                                             model.hands_mean_right, expressions);
  const Objective objective(body, map, observed, temporal_triples(numbers), silhouette, support.size(0));

  FitResult result;
  result.silhouette = use_silhouette;
  for (const StagePlan& plan : stage_plans(settings.iterations, use_silhouette, options))
    if (plan.iterations > 0) result.stages.push_back(run_stage(p, plan, objective, fit_betas, settings));
  result.poses = p.poses();
  result.betas = p.betas.detach().to(at::kCPU, at::kFloat);
  return result;
}

}  // namespace sfgs::fit
