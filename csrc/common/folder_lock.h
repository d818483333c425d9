#pragma once
// Ownership of a folder for one kind of work: a run folder is trained by one process at a time, evaluated by one at
// a time, and a render folder is written by one render at a time. The lock is an flock(2) on a hidden file in the
// folder, so the kernel drops it when its process ends, however it ends (kill -9 included): it never goes stale.
// The holder writes its pid, command and start time into the file so that whoever is refused learns who holds it.
#include <string>

namespace sfgs {

class FolderLock {
 public:
  // Creates `folder` if needed and locks it for `purpose` ("train", "eval", "render"). Throws std::runtime_error
  // naming the folder and the holder (pid, command, start) when another process holds the same lock.
  FolderLock(const std::string& folder, const std::string& purpose);
  ~FolderLock();
  FolderLock(const FolderLock&) = delete;
  FolderLock& operator=(const FolderLock&) = delete;

  // The lock file of `purpose` in `folder`.
  static std::string file_for(const std::string& folder, const std::string& purpose);

 private:
  int fd_ = -1;
};

}  // namespace sfgs
