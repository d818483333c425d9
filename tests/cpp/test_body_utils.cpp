#include "test_body_utils.h"
#include "test_files.h"

#include <cstdlib>
#include <fstream>
#include <random>

#include <ATen/ATen.h>
#include <gtest/gtest.h>
#include <c10/util/Exception.h>

namespace sfgs::testing {

ScratchFolder::ScratchFolder() {
  std::random_device random;
  path_ = std::filesystem::temp_directory_path() /
          ("sfgs_body_test_" + std::to_string(random()) + "_" + std::to_string(random()));
  std::filesystem::create_directories(path_);
}

ScratchFolder::~ScratchFolder() { remove_folder_tree(path_.string()); }

void expect_error(const std::function<void()>& f, const std::vector<std::string>& needles) {
  try {
    f();
    ADD_FAILURE() << "expected an error mentioning '" << needles.front() << "'";
  } catch (const c10::Error& e) {
    const std::string message = e.what_without_backtrace();
    for (const std::string& needle : needles)
      EXPECT_NE(message.find(needle), std::string::npos) << "'" << needle << "' is not in: " << message;
  }
}

void write_bytes(const std::string& path, const void* data, size_t size) {
  std::ofstream(path, std::ios::binary).write(static_cast<const char*>(data), static_cast<std::streamsize>(size));
}

std::vector<unsigned char> read_bytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  EXPECT_TRUE(in.good()) << "cannot read " << path;  // two missing files would otherwise compare equal
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

std::string shared_bodies_folder() {
  namespace fs = std::filesystem;
  const char* configured = std::getenv("SFGS_SHARED_DIR");
  // This file is <repository>/tests/cpp/test_body_utils.cpp; the shared folder sits next to the repository.
  const fs::path shared = configured != nullptr && *configured != '\0'
                              ? fs::path(configured)
                              : fs::path(__FILE__).parent_path().parent_path().parent_path().parent_path() / "shared";
  const fs::path bodies = shared / "bodies";
  return fs::exists(bodies / "anny_smplx_layout.npz") ? bodies.string() : std::string();
}

const body::SmplxModelData& anny_smplx() {
  static const body::SmplxModelData data =
      body::SmplxModelData::load(shared_bodies_folder() + "/anny_smplx_layout.npz");
  return data;
}

const body::ProceduralBody& procedural_body() {
  static const body::ProceduralBody body = body::make_procedural_body();
  return body;
}

bool closed_and_oriented(const at::Tensor& faces, int64_t num_vertices) {
  const at::Tensor from = faces.flatten(), to = faces.roll(-1, 1).flatten();
  const at::Tensor forward = std::get<0>((from * num_vertices + to).sort());
  const at::Tensor backward = std::get<0>((to * num_vertices + from).sort());
  const bool unique =
      forward.size(0) < 2 ||
      (forward.narrow(0, 1, forward.size(0) - 1) != forward.narrow(0, 0, forward.size(0) - 1)).all().item<bool>();
  return unique && forward.equal(backward);
}

double central_difference(const std::function<double()>& f, const at::Tensor& x, int64_t index, double step) {
  at::NoGradGuard no_grad;
  double* value = x.data_ptr<double>() + index;
  const double original = *value;
  *value = original + step;
  const double plus = f();
  *value = original - step;
  const double minus = f();
  *value = original;
  return (plus - minus) / (2 * step);
}

}  // namespace sfgs::testing
