#include "data/motions.h"
#include "common/math_constants.h"

#include <algorithm>
#include <cmath>
#include <sstream>

#include <ATen/ATen.h>

namespace sfgs::data {
namespace {

constexpr double kMotionHz = 0.5;  // every motion repeats every 2 s: a 60-frame block at 30 frames/s is one cycle

// Joint numbers follow SMPL-X (body_pose holds joints 1..21); axes are the joint's local x, y, z. In the rest pose
// (a T-pose, y up, z forward): -x at a hip swings the leg forward, +x at a knee bends it, +x at a spine joint bends
// forward, -z / +z at the left / right shoulder lowers that arm, -y / +y at the left / right shoulder brings it
// forward.
enum Joint : int64_t {
  kLeftHip = 1,
  kRightHip = 2,
  kSpine1 = 3,
  kLeftKnee = 4,
  kRightKnee = 5,
  kSpine2 = 6,
  kLeftAnkle = 7,
  kRightAnkle = 8,
  kSpine3 = 9,
  kNeck = 12,
  kHead = 15,
  kLeftShoulder = 16,
  kRightShoulder = 17,
  kLeftElbow = 18,
  kRightElbow = 19,
  kLeftWrist = 20,
  kRightWrist = 21
};

struct Pose {
  body::SmplxPose p;
  void set(int64_t joint, double x, double y, double z) {
    p.body_pose[joint - 1][0] = float(x);
    p.body_pose[joint - 1][1] = float(y);
    p.body_pose[joint - 1][2] = float(z);
  }
  void spine(double x, double y, double z) {  // spread evenly over the three spine joints
    for (int64_t j : {kSpine1, kSpine2, kSpine3}) set(j, x / 3, y / 3, z / 3);
  }
  void root(double x, double y, double z) {
    p.global_orient[0] = float(x);
    p.global_orient[1] = float(y);
    p.global_orient[2] = float(z);
  }
  void translate(double x, double y, double z) {
    p.transl[0] = float(x);
    p.transl[1] = float(y);
    p.transl[2] = float(z);
  }
};

// Fingers curling finger by finger (to `fist` extra curl), the jaw opening, the eyes looking around and the
// expression changing: shared by every motion.
void animate_hands_and_face(Pose& q, double t, double fist) {
  const double w = kTwoPi * kMotionHz;
  body::SmplxPose& p = q.p;
  p.jaw_pose[0] = float(0.12 + 0.12 * std::sin(1.3 * w * t));
  p.leye_pose[1] = p.reye_pose[1] = float(0.2 * std::sin(0.9 * w * t));
  for (int64_t k = 0; k < 15; ++k) {
    const double curl = std::min(1.4, 0.45 + 0.45 * std::sin(1.5 * w * t + 0.6 * double(k / 3)) + fist);
    p.left_hand_pose[k][2] = float(-curl);
    p.right_hand_pose[k][2] = float(curl);
  }
  for (int64_t k = 0; k < p.expression.size(0); ++k)
    p.expression[k] = float(0.8 * std::sin(w * t * (0.7 + 0.13 * double(k)) + double(k)));
}

void sway(Pose& q, double t) {
  const double w = kTwoPi * kMotionHz, s = std::sin(w * t);
  q.set(kLeftShoulder, 0.3 * s, 0, -1.1 + 0.25 * s);
  q.set(kRightShoulder, -0.3 * s, 0, 1.1 + 0.25 * s);
  q.set(kLeftElbow, 0, -0.5 - 0.4 * std::sin(w * t + 1.0), 0);
  q.set(kRightElbow, 0, 0.5 + 0.4 * std::sin(w * t + 2.0), 0);
  q.set(kLeftHip, -0.35 * s, 0, 0);
  q.set(kRightHip, 0.35 * s, 0, 0);
  q.set(kLeftKnee, 0.4 + 0.35 * std::sin(w * t + kTwoPi / 4), 0, 0);
  q.set(kRightKnee, 0.4 - 0.35 * std::sin(w * t + kTwoPi / 4), 0, 0);
  for (int64_t j : {kSpine1, kSpine2, kSpine3}) q.set(j, 0, 0.12 * std::sin(0.5 * w * t), 0);
  q.set(kNeck, 0.12 * std::sin(w * t + 0.5), 0, 0);
  q.set(kHead, 0, 0.3 * std::sin(0.7 * w * t), 0);
  q.root(0, 0.35 * std::sin(0.25 * w * t), 0);
  q.translate(0.05 * std::sin(0.5 * w * t), 0.02 * std::sin(2 * w * t), 0);
}

void walk(Pose& q, double t) {
  const double w = kTwoPi * kMotionHz, s = std::sin(w * t);
  q.set(kLeftHip, -0.5 * s, 0, 0);
  q.set(kRightHip, 0.5 * s, 0, 0);
  q.set(kLeftKnee, 0.45 + 0.4 * std::sin(w * t + kTwoPi / 4), 0, 0);
  q.set(kRightKnee, 0.45 - 0.4 * std::sin(w * t + kTwoPi / 4), 0, 0);
  q.set(kLeftAnkle, 0.15 * s, 0, 0);
  q.set(kRightAnkle, -0.15 * s, 0, 0);
  q.set(kLeftShoulder, 0, 0.45 * s, -1.25);  // arms swing against the legs
  q.set(kRightShoulder, 0, 0.45 * s, 1.25);
  q.set(kLeftElbow, 0, -0.35 - 0.15 * s, 0);
  q.set(kRightElbow, 0, 0.35 - 0.15 * s, 0);
  q.spine(0.05, 0.2 * s, 0);
  q.set(kHead, 0, -0.1 * s, 0);
  q.translate(0, 0.02 * std::abs(std::sin(w * t)), 0);
}

void wave(Pose& q, double t) {
  const double w = kTwoPi * kMotionHz, s = std::sin(w * t), fast = std::sin(3 * w * t);
  q.set(kLeftShoulder, 0, -0.1, -1.3);
  q.set(kLeftElbow, 0, -0.3, 0);
  q.set(kRightShoulder, 0, 0.2, -0.35);          // raised a little above the horizontal
  q.set(kRightElbow, 0, 0, -1.3 + 0.45 * fast);  // forearm up, waving
  q.set(kRightWrist, 0, 0, 0.3 * fast);
  q.spine(0, 0, -0.15 * s);
  q.set(kHead, 0, 0.2, 0.1 * s);
  q.set(kLeftHip, 0, 0, 0.06 * s);
  q.set(kRightHip, 0, 0, 0.06 * s);
  q.translate(0.03 * s, 0, 0);
}

void overhead(Pose& q, double t) {
  const double w = kTwoPi * kMotionHz, s = std::sin(w * t);
  q.set(kLeftShoulder, 0, 0, 1.3 + 0.15 * s);
  q.set(kRightShoulder, 0, 0, -1.3 + 0.15 * s);
  q.set(kLeftElbow, 0, -0.25 + 0.15 * s, 0);
  q.set(kRightElbow, 0, 0.25 + 0.15 * s, 0);
  q.spine(-0.1, 0, 0.45 * s);  // stretching to either side, leaning back a little
  q.set(kNeck, -0.1, 0, 0.1 * s);
  q.set(kHead, -0.15, 0, 0);
}

void bend(Pose& q, double t) {
  const double w = kTwoPi * kMotionHz;
  const double depth = 0.65 - 0.35 * std::cos(w * t);  // 0.3 .. 1.0 of the full bend
  q.root(0.6 * depth, 0, 0);                           // the pelvis tips forward ...
  q.set(kLeftHip, -0.6 * depth, 0, 0);                 // ... over legs that stay upright
  q.set(kRightHip, -0.6 * depth, 0, 0);
  q.set(kLeftKnee, 0.12 * depth, 0, 0);
  q.set(kRightKnee, 0.12 * depth, 0, 0);
  q.spine(0.9 * depth, 0, 0);
  q.set(kNeck, 0.15 * depth, 0, 0);
  q.set(kHead, -0.3 * depth, 0, 0);
  q.set(kLeftShoulder, -1.1 * depth, 0, -1.35);  // arms hanging towards the floor
  q.set(kRightShoulder, -1.1 * depth, 0, 1.35);
}

void guard(Pose& q, double t) {
  const double w = kTwoPi * kMotionHz, s = std::sin(w * t), bob = std::sin(2 * w * t);
  q.root(0.2, 0.25 * s, 0);
  q.set(kLeftHip, -0.65 - 0.1 * bob, 0, 0.1);
  q.set(kRightHip, -0.65 - 0.1 * bob, 0, -0.1);
  q.set(kLeftKnee, 0.85 + 0.2 * bob, 0, 0);
  q.set(kRightKnee, 0.85 + 0.2 * bob, 0, 0);
  q.set(kLeftAnkle, -0.25, 0, 0);
  q.set(kRightAnkle, -0.25, 0, 0);
  q.spine(0.15, -0.2 * s, 0);
  q.set(kLeftShoulder, 0, -0.7, -0.9);  // upper arms down and forward ...
  q.set(kRightShoulder, 0, 0.7, 0.9);
  q.set(kLeftElbow, 0, -2.1 + 0.15 * s, 0);  // ... fists up at the chin
  q.set(kRightElbow, 0, 2.1 + 0.15 * s, 0);
  q.set(kHead, 0.15, 0.2 * s, 0);
  q.translate(0, -0.08 - 0.02 * bob, 0);
}

void turn(Pose& q, double t) {
  const double w = kTwoPi * kMotionHz, s = std::sin(w * t);
  q.root(0, 1.2 * s, 0);
  q.set(kHead, 0, 0.3 * std::sin(w * t + 0.4), 0);  // the head leads the turn
  q.spine(0, 0.15 * std::sin(w * t + 0.2), 0);
  q.set(kLeftShoulder, 0, 0.2 * s, -1.2);
  q.set(kRightShoulder, 0, 0.2 * s, 1.2);
  q.set(kLeftElbow, 0, -0.4, 0);
  q.set(kRightElbow, 0, 0.4, 0);
  q.set(kLeftKnee, 0.15 + 0.15 * std::sin(2 * w * t), 0, 0);
  q.set(kRightKnee, 0.15 - 0.15 * std::sin(2 * w * t), 0, 0);
}

void sit(Pose& q, double t) {
  const double w = kTwoPi * kMotionHz;
  const double depth = 0.5 - 0.5 * std::cos(w * t);  // standing at t = 0, deepest at 1 s
  q.root(0.5 * depth, 0, 0);                         // the torso leans forward
  q.set(kLeftHip, -2.0 * depth, 0, 0.1 * depth);     // thighs near horizontal
  q.set(kRightHip, -2.0 * depth, 0, -0.1 * depth);
  q.set(kLeftKnee, 2.0 * depth, 0, 0);
  q.set(kRightKnee, 2.0 * depth, 0, 0);
  q.set(kLeftAnkle, -0.5 * depth, 0, 0);  // feet flat
  q.set(kRightAnkle, -0.5 * depth, 0, 0);
  q.spine(0.2 * depth, 0, 0);
  q.set(kLeftShoulder, 0, -1.3 * depth, -1.3 * (1 - depth) - 0.1);  // arms forward for balance
  q.set(kRightShoulder, 0, 1.3 * depth, 1.3 * (1 - depth) + 0.1);
  q.translate(0, -0.42 * depth, 0);
}

// Talking with the hands, facing the camera: forearms up in front of the chest, gesturing, the head nodding; no turn,
// so a video of it never shows the back.
void talk(Pose& q, double t) {
  const double w = kTwoPi * kMotionHz, s = std::sin(w * t), c = std::cos(1.5 * w * t);
  q.set(kLeftShoulder, 0, -0.5 - 0.2 * s, -1.0);  // upper arms down and forward ...
  q.set(kRightShoulder, 0, 0.5 + 0.2 * c, 1.0);
  q.set(kLeftElbow, 0, -1.4 - 0.3 * c, 0);  // ... forearms up in front, moving with the words
  q.set(kRightElbow, 0, 1.4 + 0.3 * s, 0);
  q.set(kLeftWrist, 0, 0, 0.3 * s);
  q.set(kRightWrist, 0, 0, -0.3 * c);
  q.set(kNeck, 0.1 * std::sin(2 * w * t), 0, 0);
  q.set(kHead, 0, 0.15 * s, 0.05 * c);
  q.spine(0, 0.08 * s, 0.05 * c);
  q.translate(0.02 * s, 0, 0);
}

// A slow front kick, one leg a cycle (left, then right): the leg swings forward and up nearly straight, so the sole
// faces the camera in front; arms out and the torso leaning back for balance.
void kick(Pose& q, double t) {
  const double w = kTwoPi * kMotionHz;
  const double lift = 0.5 - 0.5 * std::cos(w * t);  // standing at every cycle's start, the leg highest at its middle
  const bool left = std::fmod(t * kMotionHz, 2.0) < 1.0;
  q.set(left ? kLeftHip : kRightHip, -1.4 * lift, 0, 0);
  q.set(left ? kLeftKnee : kRightKnee, 0.25 * lift, 0, 0);
  q.spine(-0.15 * lift, 0, 0);
  q.set(kLeftShoulder, 0, -0.4 * lift, -1.0 + 0.4 * lift);
  q.set(kRightShoulder, 0, 0.4 * lift, 1.0 - 0.4 * lift);
  q.set(kHead, 0.1 * lift, 0, 0);
}

using MotionFunction = void (*)(Pose&, double);

const std::vector<std::pair<std::string, MotionFunction>>& library() {
  static const std::vector<std::pair<std::string, MotionFunction>> motions{
      {"sway", sway},   {"walk", walk}, {"wave", wave}, {"overhead", overhead}, {"bend", bend},
      {"guard", guard}, {"turn", turn}, {"sit", sit},   {"talk", talk},         {"kick", kick}};
  return motions;
}

std::string choices() {
  std::string text;
  for (const std::string& name : motion_names()) text += (text.empty() ? "" : ", ") + name;
  return text;
}

}  // namespace

const std::vector<std::string>& motion_names() {
  static const std::vector<std::string> names = [] {
    std::vector<std::string> n;
    for (const auto& [name, function] : library()) n.push_back(name);
    return n;
  }();
  return names;
}

bool is_motion(const std::string& name) {
  const auto& names = motion_names();
  return std::find(names.begin(), names.end(), name) != names.end();
}

std::vector<std::string> parse_motion_list(const std::string& text, const char* option) {
  std::vector<std::string> motions;
  std::stringstream stream(text);
  std::string name;
  while (std::getline(stream, name, ',')) {
    TORCH_CHECK(is_motion(name), option, ": unknown motion '", name, "' (the library has ", choices(), ")");
    TORCH_CHECK(std::find(motions.begin(), motions.end(), name) == motions.end(), option, ": motion '", name,
                "' is listed twice");
    motions.push_back(name);
  }
  TORCH_CHECK(!motions.empty(), option, ": expected comma-separated motion names (", choices(), "), got '", text, "'");
  return motions;
}

body::SmplxPose motion_pose(const std::string& motion, double seconds, int64_t expression_count) {
  TORCH_CHECK(std::isfinite(seconds), "motion_pose: time must be finite, got ", seconds);
  const auto& motions = library();
  const auto found = std::find_if(motions.begin(), motions.end(), [&](const auto& m) { return m.first == motion; });
  TORCH_CHECK(found != motions.end(), "unknown motion '", motion, "' (the library has ", choices(), ")");
  Pose q{body::SmplxPose::zeros(expression_count)};
  found->second(q, seconds);
  animate_hands_and_face(q, seconds, motion == "guard" ? 0.8 : 0.0);
  return q.p;
}

}  // namespace sfgs::data
