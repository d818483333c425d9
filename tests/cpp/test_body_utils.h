#pragma once
// Shared fixtures of the .npz and body-model tests: scratch folders, error-message checks, the procedural body
// built once per process, and the CC0 Anny stand-ins in the official layouts (../shared/bodies, or
// $SFGS_SHARED_DIR/bodies); tests that need those skip with a message when they are absent.
#include <cstddef>
#include <filesystem>
#include <functional>
#include <string>
#include <vector>

#include <ATen/core/Tensor.h>
#include <gtest/gtest.h>

#include "body/procedural_body.h"
#include "body/smplx.h"

namespace sfgs::testing {

// A fresh folder under the system temporary directory, removed with its contents at the end of the scope.
class ScratchFolder {
 public:
  ScratchFolder();
  ~ScratchFolder();
  std::string file(const std::string& name) const { return (path_ / name).string(); }
  std::string str() const { return path_.string(); }

 private:
  std::filesystem::path path_;
};

// Runs f and expects a c10::Error whose message contains every one of `needles`.
void expect_error(const std::function<void()>& f, const std::vector<std::string>& needles);

void write_bytes(const std::string& path, const void* data, size_t size);
std::vector<unsigned char> read_bytes(const std::string& path);

// The folder holding anny_smplx_layout.npz and the MANO-layout stand-ins, or "" when it is absent.
std::string shared_bodies_folder();
#define SFGS_SKIP_WITHOUT_SHARED_BODIES()                                                                        \
  if (sfgs::testing::shared_bodies_folder().empty())                                                             \
  GTEST_SKIP() << "the CC0 body stand-ins are absent: expected ../shared/bodies next to the repository, or set " \
                  "SFGS_SHARED_DIR to the folder that holds bodies/anny_smplx_layout.npz"

// Loaded once per process (reading the 3.5 MB archive inflates ~280 MB of blend shapes).
const body::SmplxModelData& anny_smplx();
const body::ProceduralBody& procedural_body();

// Whether every directed edge of the triangles occurs exactly once and so does its reverse: a closed,
// consistently oriented 2-manifold.
bool closed_and_oriented(const at::Tensor& faces, int64_t num_vertices);

// Central difference of f with respect to entry `index` of the flattened double tensor x (restored afterwards).
double central_difference(const std::function<double()>& f, const at::Tensor& x, int64_t index, double step);

}  // namespace sfgs::testing
