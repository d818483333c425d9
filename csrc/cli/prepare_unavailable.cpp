// Stands in for prepare_command.cpp in builds without person detection (no FlatBuffers headers).
#include <c10/util/Exception.h>

#include "cli/commands.h"

namespace sfgs::cli {

int run_prepare(Arguments&) {
  TORCH_CHECK(false,
              "this build of sfgs has no person detection: install libflatbuffers-dev "
              "(scripts/install_deps.sh) and build again");
}

}  // namespace sfgs::cli
