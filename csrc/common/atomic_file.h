#pragma once
// Files the user keeps are never left half-written: bytes go to a temporary file in the same folder, which is
// flushed and then renamed over the target in one step.
#include <string>
#include <vector>

namespace sfgs {

// Writes `bytes` to `path` atomically. Refuses to replace an existing file unless `overwrite` is set.
// Throws std::runtime_error naming the file on any failure.
void write_file_atomically(const std::string& path, const std::vector<unsigned char>& bytes, bool overwrite);

}  // namespace sfgs
