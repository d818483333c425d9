#pragma once
// The web viewer's own files (web/: index.html and its scripts), embedded into the executable when it is built
// (cmake/embed_files.cmake writes the source that defines web_assets()): an export works wherever the executable
// has been moved, and always carries the viewer of the version that wrote its data.
#include <cstddef>
#include <vector>

namespace sfgs::train {

struct WebAsset {
  const char* name;  // the file's name in web/ (and in the exported folder)
  const unsigned char* bytes;
  size_t size;
};

const std::vector<WebAsset>& web_assets();

}  // namespace sfgs::train
