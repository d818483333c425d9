// The test runner: GoogleTest's main plus a crash report, so that a test dying on a signal (on a machine where no
// debugger is at hand) names where it died: the faulting instruction, the return address on top of the stack (the
// caller, when the fault is a call through a bad pointer, which ends the unwound stack) and the unwound frames.
#include <csignal>
#include <cstdint>
#include <cstdio>

#include <execinfo.h>
#include <gtest/gtest.h>
#include <ucontext.h>
#include <unistd.h>

namespace {

void report_crash(int signal_number, siginfo_t* info, void* context) {
  void* frames[64];
  int count = 0;
#if defined(__x86_64__)
  const auto* registers = static_cast<ucontext_t*>(context)->uc_mcontext.gregs;
  frames[count++] = reinterpret_cast<void*>(registers[REG_RIP]);
  frames[count++] = *reinterpret_cast<void**>(registers[REG_RSP]);
#endif
  count += backtrace(frames + count, 64 - count);
  char header[96];
  const int length = std::snprintf(header, sizeof(header), "\nsfgs_tests: signal %d at address %p; stack:\n",
                                   signal_number, info->si_addr);
  (void)!write(STDERR_FILENO, header, size_t(length));
  backtrace_symbols_fd(frames, count, STDERR_FILENO);
  std::signal(signal_number, SIG_DFL);
  std::raise(signal_number);
}

}  // namespace

int main(int argc, char** argv) {
  struct sigaction action = {};
  action.sa_sigaction = report_crash;
  action.sa_flags = SA_SIGINFO;
  for (const int s : {SIGSEGV, SIGBUS, SIGFPE, SIGILL}) sigaction(s, &action, nullptr);
  testing::InitGoogleTest(&argc, argv);
  return RUN_ALL_TESTS();
}
