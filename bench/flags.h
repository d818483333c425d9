#pragma once
// The benchmark programs' command lines: `--flag value` pairs.
#include <sstream>
#include <string>
#include <vector>

namespace sfgs::bench {

// Calls take(flag, value) for each `--flag value` pair of argv[1..], in order; calls `usage` (which must not return)
// for a flag without its value or one that `take` does not know (it returns false).
template <typename Take> void parse_flags(int argc, char** argv, void (*usage)(), Take&& take) {
  for (int i = 1; i < argc; i += 2)
    if (i + 1 >= argc || !take(std::string(argv[i]), std::string(argv[i + 1]))) usage();
}

// The comma-separated items of a flag's value ("0.3,0.5,1"), each through convert(item); calls `usage` when there are
// none.
template <typename T, typename Convert>
std::vector<T> listed(const std::string& value, void (*usage)(), Convert&& convert) {
  std::vector<T> items;
  std::stringstream list(value);
  for (std::string item; std::getline(list, item, ',');) items.push_back(convert(item));
  if (items.empty()) usage();
  return items;
}

}  // namespace sfgs::bench
