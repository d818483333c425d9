#pragma once
// Files the user keeps are never left half-written: bytes go to a temporary file in the same folder, which is
// flushed to the disk and then renamed over the target in one step (and the folder's entry is flushed too). A
// process killed in between leaves only its temporary, named `<target>.tmp-<pid>[...]`, which the next command
// working in that folder removes. Folders written as one piece (AtomicFolder) work the same way.
#include <string>
#include <vector>

namespace sfgs {

// Writes `bytes` to `path` atomically. Refuses to replace an existing file unless `overwrite` is set.
// Throws std::runtime_error naming the file on any failure (a full disk included); nothing is left behind then.
void write_file_atomically(const std::string& path, const std::vector<unsigned char>& bytes, bool overwrite);

// Removes a file or a folder and everything in it (links are removed, not followed); false when something stayed or
// nothing was there. Use it instead of std::filesystem::remove_all: the pip wheels of LibTorch 2.x export their own
// build of that function, which the dynamic linker binds our calls to and which crashes when called from code built
// with GCC 13 (pytorch/pytorch#133437).
bool remove_tree(const std::string& path);

// The name a process gives its temporary copy of `path` ("<path>.tmp-<pid>"); `suffix` is appended (a video
// writer needs the container's extension).
std::string temporary_path(const std::string& path, const std::string& suffix = "");

// Flushes `path` (a file written by other means, e.g. a library's encoder) to the disk and moves it to `target`
// atomically, flushing the folder's entry. Throws naming both on failure, and then removes `path`.
void commit_file(const std::string& path, const std::string& target);

// Removes the temporaries (`*.tmp-<pid>*`, files and folders) in `folder` whose process no longer runs: what a
// killed run left behind. Returns the names removed.
std::vector<std::string> remove_stale_temporaries(const std::string& folder);

// A folder that appears complete or not at all: its files are written into a temporary sibling folder, which
// commit() renames to the target in one step. Destroyed without commit() (an error on the way), it removes the
// temporary folder and leaves the target as it was.
class AtomicFolder {
 public:
  // The target's parent folder must exist. Throws naming the folder when the temporary cannot be created.
  explicit AtomicFolder(const std::string& target);
  ~AtomicFolder();
  AtomicFolder(const AtomicFolder&) = delete;
  AtomicFolder& operator=(const AtomicFolder&) = delete;

  // Writes `bytes` to `relative_path` inside the folder (creating its subfolders); throws naming the file.
  void add(const std::string& relative_path, const std::vector<unsigned char>& bytes);
  // Puts the folder in place. An existing empty folder is replaced; any other existing target only when `overwrite`
  // (moved aside first and removed once the new folder is in place), otherwise it is an error naming it.
  void commit(bool overwrite);

 private:
  std::string target_, temporary_;
  bool committed_ = false;
};

}  // namespace sfgs
