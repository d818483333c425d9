#pragma once
// Command-line options of the sfgs subcommands: `--name value` (or `--name=value`) pairs and `--flag` switches, each
// given at most once and read once; anything unread is reported as unknown, so a typo never passes silently, and a
// value that looks like an option (`--out --force`) is refused rather than taken as a folder name.
#include <array>
#include <cstdint>
#include <map>
#include <set>
#include <string>
#include <vector>
#include "ops/splat/constants.h"

namespace sfgs::cli {

class Arguments {
 public:
  // argv after the subcommand; `flags` names the options that take no value.
  Arguments(const std::vector<std::string>& args, const std::set<std::string>& flags);
  std::string text(const std::string& name, const std::string& fallback);
  std::string required(const std::string& name);
  int64_t integer(const std::string& name, int64_t fallback, int64_t lo, int64_t hi);
  double real(const std::string& name, double fallback, double lo, double hi);
  bool flag(const std::string& name);
  // An image size written WIDTHxHEIGHT (540x960), each side in [1, kMaxImageSide]; {0, 0} when not given.
  std::array<int64_t, 2> image_size(const std::string& name);
  bool has(const std::string& name) const { return values_.count(name) > 0 || flags_.count(name) > 0; }
  // Throws naming every option that was given but never read.
  void finish() const;
  // The options as given, joined by spaces (what a result records of the command that wrote it).
  const std::string& line() const { return line_; }

 private:
  std::map<std::string, std::string> values_;
  std::set<std::string> flags_;
  std::set<std::string> read_;
  std::string line_;
};

}  // namespace sfgs::cli
