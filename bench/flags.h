#pragma once
// The benchmark programs' command lines: `--flag value` pairs.
#include <string>

namespace sfgs::bench {

// Calls take(flag, value) for each `--flag value` pair of argv[1..], in order; calls `usage` (which must not return)
// for a flag without its value or one that `take` does not know (it returns false).
template <typename Take> void parse_flags(int argc, char** argv, void (*usage)(), Take&& take) {
  for (int i = 1; i < argc; i += 2)
    if (i + 1 >= argc || !take(std::string(argv[i]), std::string(argv[i + 1]))) usage();
}

}  // namespace sfgs::bench
