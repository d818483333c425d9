#include "common/folder_lock.h"

#include <cerrno>
#include <chrono>
#include <cstring>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <stdexcept>

#include <fcntl.h>
#include <sys/file.h>
#include <unistd.h>

namespace sfgs {
namespace fs = std::filesystem;

namespace {

// The command line of this process, from /proc (empty where there is none).
std::string own_command_line() {
  std::ifstream in("/proc/self/cmdline", std::ios::binary);
  std::string raw((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  for (char& c : raw)
    if (c == '\0') c = ' ';
  while (!raw.empty() && raw.back() == ' ') raw.pop_back();
  return raw;
}

std::string now_text() {
  const std::time_t t = std::chrono::system_clock::to_time_t(std::chrono::system_clock::now());
  char buffer[32];
  std::strftime(buffer, sizeof(buffer), "%Y-%m-%d %H:%M:%S", std::localtime(&t));
  return buffer;
}

// "pid 1234, `sfgs train --data ...`, since 2026-11-24 19:00:01" from the holder's lock file.
std::string describe_holder(const std::string& path) {
  std::ifstream in(path);
  std::string pid, command, since, line;
  while (std::getline(in, line)) {
    if (line.rfind("pid ", 0) == 0) pid = line.substr(4);
    if (line.rfind("command ", 0) == 0) command = line.substr(8);
    if (line.rfind("since ", 0) == 0) since = line.substr(6);
  }
  if (pid.empty()) return "another process (it has not written its pid yet)";
  std::string text = "pid " + pid;
  if (!command.empty()) text += ", `" + command + "`";
  if (!since.empty()) text += ", since " + since;
  return text;
}

}  // namespace

std::string FolderLock::file_for(const std::string& folder, const std::string& purpose) {
  return (fs::path(folder) / (".sfgs-" + purpose + ".lock")).string();
}

FolderLock::FolderLock(const std::string& folder, const std::string& purpose) {
  std::error_code ec;
  fs::create_directories(folder, ec);
  if (ec) throw std::runtime_error("cannot create folder '" + folder + "': " + ec.message());
  const std::string path = file_for(folder, purpose);
  fd_ = ::open(path.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
  if (fd_ < 0) throw std::runtime_error("cannot open the lock file '" + path + "': " + std::strerror(errno));
  if (::flock(fd_, LOCK_EX | LOCK_NB) != 0) {
    const int error = errno;
    ::close(fd_);
    fd_ = -1;
    if (error != EWOULDBLOCK) throw std::runtime_error("cannot lock '" + path + "': " + std::strerror(error));
    throw std::runtime_error("folder '" + folder + "' is in use by another sfgs " + purpose + " (" +
                             describe_holder(path) + "); wait for it to finish or stop it: two at once would mix " +
                             "their files");
  }
  std::ostringstream holder;
  holder << "pid " << ::getpid() << "\ncommand " << own_command_line() << "\nsince " << now_text() << "\n";
  const std::string text = holder.str();
  // Best effort: the lock itself is the flock; the text only names the holder to whoever is refused.
  if (::ftruncate(fd_, 0) == 0 && ::pwrite(fd_, text.data(), text.size(), 0) == ssize_t(text.size())) ::fsync(fd_);
}

FolderLock::~FolderLock() {
  if (fd_ >= 0) ::close(fd_);  // closing the only descriptor releases the flock
}

}  // namespace sfgs
