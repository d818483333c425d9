#pragma once
// The sfgs subcommands; each returns the process exit code and throws on bad input with a message for the user.
#include "cli/arguments.h"

namespace sfgs::cli {

int run_synth(Arguments& args);
int run_fit(Arguments& args);
int run_prepare(Arguments& args);
int run_train(Arguments& args);
int run_eval(Arguments& args);
int run_render(Arguments& args);
int run_export(Arguments& args);
int run_ablate(Arguments& args);
int run_demo(Arguments& args);
int run_bench(Arguments& args);

}  // namespace sfgs::cli
