#pragma once
// `sfgs export --web`: a trained avatar playing a motion, as a folder that a browser with WebGL2 opens from the disk
// (docs/web_viewer.md). The folder holds index.html, the viewer's scripts (web/, embedded into the executable) and
// the data as scripts that assign base64 text (browsers refuse to fetch file:// URLs but run scripts from them):
// the canonical Gaussians of the rest pose, their strongest joint influences, every frame's joint transforms, and
// per frame the quantised difference between the avatar's posed means and log scales and what skinning the rest
// pose gives. The viewer skins, shades (the avatar's shading of the skinned normal), depth-sorts and splats them as
// sfgs::render does.
#include <array>
#include <cstdint>
#include <functional>
#include <string>

#include "model/avatar.h"
#include "ops/splat/splat.h"

namespace sfgs::train {

struct WebMotion {
  std::string name;  // shown by the viewer
  int64_t frames = 0;
  double frames_per_second = 0;
  std::function<model::AvatarOutput(int64_t)> pose;  // frame i on the avatar (as a new motion: no frame time)
};

// The still camera the viewer's `?camera=render` shows (docs/web_viewer.md), and the point its orbit turns about.
struct WebCamera {
  Camera camera;
  std::array<double, 3> target;
};

struct WebExportSummary {
  int64_t gaussians = 0, joints = 0, influences = 0, frames = 0;
  int64_t static_bytes = 0;   // the data every frame shares (before base64)
  int64_t frame_bytes = 0;    // the data of one frame (before base64)
  int64_t folder_bytes = 0;   // every file written
  double largest_offset = 0;  // metres: the largest posed mean's distance from the viewer's skinning of the rest
  std::string note;           // what the viewer leaves out for this avatar; empty when nothing
};

// Writes the folder atomically (it appears complete or not at all). An existing folder is replaced only when it is
// empty, or when `overwrite` and it is an earlier web export; errors name the folder.
WebExportSummary export_web_viewer(model::Avatar& avatar, const WebMotion& motion, const WebCamera& camera,
                                   const std::string& folder, bool overwrite);

// Throws what export_web_viewer would throw for this folder: a caller checks before its own long work.
void check_web_folder(const std::string& folder, bool overwrite);

}  // namespace sfgs::train
