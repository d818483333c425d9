#include "common/atomic_file.h"

#include <cerrno>
#include <csignal>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <regex>
#include <stdexcept>

#include <fcntl.h>
#include <ftw.h>
#include <unistd.h>

namespace sfgs {
namespace fs = std::filesystem;

namespace {

// Makes a rename durable: the new directory entry reaches the disk too, not only the file's bytes.
void sync_folder_of(const std::string& path) {
  const fs::path parent = fs::path(path).has_parent_path() ? fs::path(path).parent_path() : fs::path(".");
  const int fd = ::open(parent.c_str(), O_RDONLY | O_DIRECTORY);
  if (fd < 0) return;  // a folder that cannot be opened for reading still got the rename; nothing more to do
  ::fsync(fd);
  ::close(fd);
}

bool process_runs(long pid) { return ::kill(pid_t(pid), 0) == 0 || errno == EPERM; }

}  // namespace

bool remove_tree(const std::string& path) {
  const auto remove_entry = [](const char* entry, const struct stat*, int, struct FTW*) { return ::remove(entry); };
  return ::nftw(path.c_str(), remove_entry, 16, FTW_DEPTH | FTW_PHYS) == 0;
}

std::string temporary_path(const std::string& path, const std::string& suffix) {
  return path + ".tmp-" + std::to_string(::getpid()) + suffix;
}

void write_file_atomically(const std::string& path, const std::vector<unsigned char>& bytes, bool overwrite) {
  if (!overwrite && fs::exists(path))
    throw std::runtime_error("refusing to overwrite existing file '" + path + "' (pass --force to replace it)");
  const fs::path target(path);
  if (target.has_parent_path() && !fs::is_directory(target.parent_path()))
    throw std::runtime_error("cannot write '" + path + "': folder '" + target.parent_path().string() +
                             "' does not exist");
  const std::string temporary = temporary_path(path);
  FILE* f = std::fopen(temporary.c_str(), "wb");
  if (!f) throw std::runtime_error("cannot create '" + temporary + "': " + std::strerror(errno));
  const bool written =
      std::fwrite(bytes.data(), 1, bytes.size(), f) == bytes.size() && std::fflush(f) == 0 && ::fsync(::fileno(f)) == 0;
  const int write_error = errno;
  const bool closed = std::fclose(f) == 0;
  if (!written || !closed || std::rename(temporary.c_str(), path.c_str()) != 0) {
    const std::string reason = std::strerror(!written ? write_error : errno);
    std::remove(temporary.c_str());
    throw std::runtime_error("cannot write '" + path + "': " + reason);
  }
  sync_folder_of(path);
}

void commit_file(const std::string& path, const std::string& target) {
  const int fd = ::open(path.c_str(), O_RDONLY);
  const bool synced = fd >= 0 && ::fsync(fd) == 0;
  const int sync_error = errno;
  if (fd >= 0) ::close(fd);
  if (!synced || std::rename(path.c_str(), target.c_str()) != 0) {
    const std::string reason = std::strerror(!synced ? sync_error : errno);
    std::remove(path.c_str());
    throw std::runtime_error("cannot write '" + target + "': " + reason);
  }
  sync_folder_of(target);
}

std::vector<std::string> remove_stale_temporaries(const std::string& folder) {
  std::vector<std::string> removed;
  std::error_code ec;
  if (!fs::is_directory(folder, ec)) return removed;
  static const std::regex temporary(R"(.+\.tmp-([0-9]{1,9})(\..*)?)");
  for (const fs::directory_entry& entry : fs::directory_iterator(folder, ec)) {
    const std::string name = entry.path().filename().string();
    std::smatch m;
    const bool folder_write = entry.is_directory(ec);
    if (!(entry.is_regular_file(ec) || folder_write) || !std::regex_match(name, m, temporary)) continue;
    const long pid = std::stol(m[1].str());
    if (pid == long(::getpid()) || process_runs(pid)) continue;
    if (folder_write ? remove_tree(entry.path().string()) : fs::remove(entry.path(), ec)) removed.push_back(name);
  }
  return removed;
}

AtomicFolder::AtomicFolder(const std::string& target) : target_(target), temporary_(temporary_path(target)) {
  const fs::path parent = fs::path(target).has_parent_path() ? fs::path(target).parent_path() : fs::path(".");
  if (!fs::is_directory(parent))
    throw std::runtime_error("cannot write folder '" + target + "': folder '" + parent.string() + "' does not exist");
  remove_tree(temporary_);  // this process's own leftover, if any
  std::error_code ec;
  if (!fs::create_directory(temporary_, ec))
    throw std::runtime_error("cannot create folder '" + temporary_ + "': " + ec.message());
}

AtomicFolder::~AtomicFolder() {
  if (!committed_) remove_tree(temporary_);
}

void AtomicFolder::add(const std::string& relative_path, const std::vector<unsigned char>& bytes) {
  const fs::path path = fs::path(temporary_) / relative_path;
  std::error_code ec;
  fs::create_directories(path.parent_path(), ec);
  if (ec) throw std::runtime_error("cannot create folder '" + path.parent_path().string() + "': " + ec.message());
  write_file_atomically(path.string(), bytes, false);
}

void AtomicFolder::commit(bool overwrite) {
  std::error_code ec;
  // rename() replaces an empty folder by itself; anything else is moved aside first.
  const bool replaces = fs::exists(target_, ec) && !(fs::is_directory(target_, ec) && fs::is_empty(target_, ec));
  if (replaces && !overwrite)
    throw std::runtime_error("refusing to replace existing '" + target_ + "' (pass --force to replace it)");
  const std::string aside = temporary_path(target_, ".old");
  if (replaces && std::rename(target_.c_str(), aside.c_str()) != 0)
    throw std::runtime_error("cannot replace '" + target_ + "': " + std::strerror(errno));
  if (std::rename(temporary_.c_str(), target_.c_str()) != 0) {
    const std::string reason = std::strerror(errno);
    if (replaces) std::rename(aside.c_str(), target_.c_str());  // the old folder back where it was
    throw std::runtime_error("cannot write folder '" + target_ + "': " + reason);
  }
  committed_ = true;
  sync_folder_of(target_);
  if (replaces) remove_tree(aside);
}

}  // namespace sfgs
