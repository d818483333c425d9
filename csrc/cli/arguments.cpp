#include "cli/arguments.h"

#include <cstdio>
#include <stdexcept>

#include "ops/splat/constants.h"

namespace sfgs::cli {

Arguments::Arguments(const std::vector<std::string>& args, const std::set<std::string>& flags) {
  for (const std::string& a : args) line_ += (line_.empty() ? "" : " ") + a;
  for (size_t i = 0; i < args.size(); ++i) {
    const std::string& a = args[i];
    if (a.rfind("--", 0) != 0 || a.size() == 2)
      throw std::invalid_argument("unexpected argument '" + a + "' (options start with --)");
    // --name=value takes any value, one that starts with -- included.
    const size_t equals = a.find('=');
    const std::string name = a.substr(2, equals == std::string::npos ? std::string::npos : equals - 2);
    if (values_.count(name) || flags_.count(name)) throw std::invalid_argument("option --" + name + " is given twice");
    if (flags.count(name)) {
      if (equals != std::string::npos) throw std::invalid_argument("option --" + name + " takes no value");
      flags_.insert(name);
    } else if (equals != std::string::npos) {
      values_[name] = a.substr(equals + 1);
    } else {
      if (i + 1 >= args.size()) throw std::invalid_argument("option --" + name + " needs a value");
      const std::string& value = args[i + 1];
      if (value.rfind("--", 0) == 0)
        throw std::invalid_argument("option --" + name + " needs a value, but the next argument is the option '" +
                                    value + "' (write --" + name + "=" + value + " if that really is the value)");
      values_[name] = value;
      ++i;
    }
  }
}

std::string Arguments::text(const std::string& name, const std::string& fallback) {
  read_.insert(name);
  const auto it = values_.find(name);
  return it == values_.end() ? fallback : it->second;
}

std::string Arguments::required(const std::string& name) {
  read_.insert(name);
  const auto it = values_.find(name);
  if (it == values_.end()) throw std::invalid_argument("missing required option --" + name);
  return it->second;
}

int64_t Arguments::integer(const std::string& name, int64_t fallback, int64_t lo, int64_t hi) {
  const std::string v = text(name, "");
  if (v.empty()) return fallback;
  size_t used = 0;
  int64_t x = 0;
  try {
    x = std::stoll(v, &used);
  } catch (const std::exception&) {
    used = 0;
  }
  if (used != v.size() || x < lo || x > hi)
    throw std::invalid_argument("--" + name + " expects an integer in [" + std::to_string(lo) + ", " +
                                std::to_string(hi) + "], got '" + v + "'");
  return x;
}

double Arguments::real(const std::string& name, double fallback, double lo, double hi) {
  const std::string v = text(name, "");
  if (v.empty()) return fallback;
  size_t used = 0;
  double x = 0;
  try {
    x = std::stod(v, &used);
  } catch (const std::exception&) {
    used = 0;
  }
  if (used != v.size() || !(x >= lo && x <= hi))
    throw std::invalid_argument("--" + name + " expects a number in [" + std::to_string(lo) + ", " +
                                std::to_string(hi) + "], got '" + v + "'");
  return x;
}

std::array<int64_t, 2> Arguments::image_size(const std::string& name) {
  const std::string v = text(name, "");
  if (v.empty()) return {0, 0};
  long width = 0, height = 0;
  char rest = 0;
  if (std::sscanf(v.c_str(), "%ldx%ld%c", &width, &height, &rest) != 2 || width < 1 || height < 1 ||
      width > kMaxImageSide || height > kMaxImageSide)
    throw std::invalid_argument("--" + name + " must be WIDTHxHEIGHT (for example 540x960), each side in [1, " +
                                std::to_string(kMaxImageSide) + "], got '" + v + "'");
  return {width, height};
}

bool Arguments::flag(const std::string& name) {
  read_.insert(name);
  return flags_.count(name) > 0;
}

void Arguments::finish() const {
  std::string unknown;
  for (const auto& [name, value] : values_)
    if (!read_.count(name)) unknown += " --" + name;
  for (const auto& name : flags_)
    if (!read_.count(name)) unknown += " --" + name;
  if (!unknown.empty()) throw std::invalid_argument("unknown option(s):" + unknown);
}

}  // namespace sfgs::cli
