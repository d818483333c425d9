#pragma once
// Motions from files, to drive a trained avatar with motions it never saw (`sfgs render --motion FILE`).
//
// AMASS SMPL-X .npz: `poses` (T, 165: root, 21 body joints, jaw, two eyes, 2 x 15 hand joints) or the separate
// `root_orient` (T, 3), `pose_body` (T, 63), `pose_jaw` (T, 3), `pose_eye` (T, 6), `pose_hand` (T, 90); `trans`
// (T, 3, optional); the frame rate in `mocap_frame_rate` or `mocap_framerate`. AMASS SMPL-H .npz (`poses` (T, 156):
// root, body, hands, no face) are accepted with a note: jaw and eyes stay at rest. AMASS is Z-up; the clip is
// rotated into the avatar's Y-up frame (global orientation and translation; the constant offset SMPL-X's rotation
// about the pelvis adds stays, and the cameras frame the body itself). The file's `betas` and `gender` are not used:
// the avatar keeps its subject's shape. Hand poses are absolute (relative to a flat hand).
//
// ExAvatar/SFGS motion folders: smplx_optimized/smplx_params_smoothed/N.json (ExAvatar's per-frame SMPL-X
// parameters, in the camera's coordinates; frames in numeric order) and, when present, cam_params/N.json (the frame's
// camera, "R" (3, 3) and "t" (3), world to camera). With cameras every frame is brought into the first frame's camera
// (a moving camera's motion is taken out); the camera's frame (y down, z forward) is then turned into the avatar's
// (y up, the body facing the camera facing +z). 30 frames/s (ExAvatar's videos); hands relative to the mean hand.
// docs/motions.md.
#include <limits>
#include <string>
#include <vector>

#include "body/smplx_pose.h"

namespace sfgs::data {

struct MotionClip {
  std::vector<body::SmplxPose> poses;  // one per frame, float64 on the CPU, in the avatar's Y-up frame
  double frames_per_second = 0;
  std::string source;          // the file
  std::string format;          // "amass-smplx", "amass-smplh" or "exavatar"
  bool absolute_hands = true;  // hand poses relative to a flat hand (not to the model's mean hand)
  std::string note;            // what the reader filled in or left out, for the user; empty when nothing

  double seconds() const { return poses.empty() ? 0 : double(poses.size()) / frames_per_second; }
};

// Whether `path` names a motion this reader takes: a .npz, or a folder holding smplx_optimized/smplx_params_smoothed.
bool is_motion_file(const std::string& path);

// Reads an AMASS-format .npz: its first `seconds` (the frames a resampling over them needs; all by default).
// Frame rates outside [1, 1000] frames/s, joint rotations beyond 100 rad, translations beyond 10 km and more than
// 200,000 frames read are refused before any frame is built. Errors name the file, the key and what was expected.
MotionClip read_amass(const std::string& path, double seconds = std::numeric_limits<double>::infinity());
// Reads an ExAvatar/SFGS motion folder (its first `seconds`): consecutive frame files, cameras that are rotations.
// Errors name the file and what was expected.
MotionClip read_exavatar_motion(const std::string& folder, double seconds = std::numeric_limits<double>::infinity());
// Either, by what `path` is (is_motion_file).
MotionClip read_motion(const std::string& path, double seconds = std::numeric_limits<double>::infinity());

// The clip sampled at `frames_per_second` over its duration: rotations interpolated along the shortest arc between
// the neighbouring source frames (per joint), translations and expressions linearly. The first output frame is the
// first source frame. More than 200,000 output frames are refused before any is made.
MotionClip resample(const MotionClip& clip, double frames_per_second);

}  // namespace sfgs::data
