#pragma once
// Temporary folders, small text files and error-message checks for tests that read and write files.
#include <cstdio>
#include <exception>
#include <filesystem>
#include <fstream>
#include <random>
#include <string>

#include <c10/util/Exception.h>
#include <ftw.h>
#include <gtest/gtest.h>

namespace sfgs::testing {

// Deletes a folder and everything in it (nothing if it does not exist). Not std::filesystem::remove_all: the pip
// wheels of LibTorch 2.x export their own build of it, which the dynamic linker binds our calls to and which crashes
// when called from code built with GCC 13.
inline void remove_folder_tree(const std::string& path) {
  nftw(
      path.c_str(), [](const char* entry, const struct stat*, int, struct FTW*) { return ::remove(entry); }, 16,
      FTW_DEPTH | FTW_PHYS);
}

// A fresh folder under the system temp directory, removed with everything in it when the object dies.
class TempFolder {
 public:
  TempFolder() {
    std::random_device rd;
    path_ = std::filesystem::temp_directory_path() / ("sfgs_test_" + std::to_string(rd()) + std::to_string(rd()));
    std::filesystem::create_directories(path_);
  }
  ~TempFolder() { remove_folder_tree(path_.string()); }
  std::string operator/(const std::string& relative) const {
    const std::filesystem::path p = path_ / relative;
    std::filesystem::create_directories(p.parent_path());
    return p.string();
  }
  std::string str() const { return path_.string(); }

 private:
  std::filesystem::path path_;
};

inline void write_text(const std::string& path, const std::string& text) { std::ofstream(path) << text; }

// Runs f and expects an error whose message contains `needle`.
template <typename F> void expect_error_mentioning(F&& f, const std::string& needle) {
  try {
    f();
    ADD_FAILURE() << "expected an error mentioning '" << needle << "'";
  } catch (const c10::Error& e) {
    EXPECT_NE(std::string(e.what_without_backtrace()).find(needle), std::string::npos) << e.what_without_backtrace();
  } catch (const std::exception& e) {
    EXPECT_NE(std::string(e.what()).find(needle), std::string::npos) << e.what();
  }
}

}  // namespace sfgs::testing
