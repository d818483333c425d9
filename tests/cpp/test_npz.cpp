// The .npy / .npz reader and writer (csrc/io/npz.h): every dtype numpy writes, both byte orders, C and Fortran
// order, stored and deflated members, byte-identical headers, and clear errors for every kind of bad file.
#include <algorithm>
#include <cstring>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "io/npz.h"
#include "test_body_utils.h"

namespace sfgs::testing {

extern const unsigned char kNumpyStored[];
extern const size_t kNumpyStoredSize;
extern const unsigned char kNumpyDeflated[];
extern const size_t kNumpyDeflatedSize;

namespace {

using io::NpzArchive;

void expect_equal(const at::Tensor& actual, const at::Tensor& expected) {
  EXPECT_EQ(actual.scalar_type(), expected.scalar_type());
  EXPECT_EQ(actual.sizes(), expected.sizes());
  EXPECT_TRUE(actual.is_contiguous());
  if (actual.sizes() == expected.sizes()) EXPECT_TRUE(actual.equal(expected)) << actual << "\nexpected\n" << expected;
}

std::string numpy_archive(const ScratchFolder& folder, const unsigned char* bytes, size_t size, const char* name) {
  const std::string path = folder.file(name);
  write_bytes(path, bytes, size);
  return path;
}

// A raw .npy file: numpy's magic, version 1.0, the given header dict padded like numpy's, then `data`.
std::string raw_npy(const ScratchFolder& folder, const std::string& dict, const std::vector<unsigned char>& data) {
  std::string header = dict;
  while ((10 + header.size() + 1) % 64 != 0) header += ' ';
  header += '\n';
  std::vector<unsigned char> bytes = {0x93,
                                      'N',
                                      'U',
                                      'M',
                                      'P',
                                      'Y',
                                      1,
                                      0,
                                      static_cast<unsigned char>(header.size()),
                                      static_cast<unsigned char>(header.size() >> 8)};
  bytes.insert(bytes.end(), header.begin(), header.end());
  bytes.insert(bytes.end(), data.begin(), data.end());
  const std::string path = folder.file("raw.npy");
  write_bytes(path, bytes.data(), bytes.size());
  return path;
}

TEST(Npz, ReadsEveryDtypeNumpyWrites) {
  ScratchFolder folder;
  const NpzArchive npz(numpy_archive(folder, kNumpyStored, kNumpyStoredSize, "numpy_stored.npz"));
  EXPECT_EQ(npz.keys(), (std::vector<std::string>{"f4", "f8_fortran", "i4", "i8", "u4", "u8", "b1", "f8_big", "i2_big",
                                                  "u2", "u1", "i1", "f2", "scalar", "empty"}));
  expect_equal(npz.read("f4"), at::tensor({1.5, -2.25, 3.0, 4.0, 5.5, -6.75}, at::kFloat).view({2, 3}));
  expect_equal(npz.read("f8_fortran"), at::tensor({1.0, 2.0, 3.0, 4.0, 5.0, 6.0}, at::kDouble).view({3, 2}));
  expect_equal(npz.read("i4"), at::tensor({-7, 0, 2147483647}, at::kInt));
  expect_equal(npz.read("i8"), at::tensor({int64_t{-9223372036854775807}, int64_t{5}}, at::kLong).view({1, 2}));
  expect_equal(npz.read("u4"), at::tensor({int64_t{4294967295}, int64_t{1}}, at::kLong));
  expect_equal(npz.read("u8"), at::tensor({int64_t{3}, int64_t{18}}, at::kLong));
  expect_equal(npz.read("b1"), at::tensor({1, 0, 1}, at::kInt).to(at::kBool));
  expect_equal(npz.read("f8_big"), at::tensor({0.5, -1.25}, at::kDouble));
  expect_equal(npz.read("i2_big"), at::tensor({-300, 300}, at::kInt).to(at::kShort));
  expect_equal(npz.read("u2"), at::tensor({65535, 7}, at::kInt));
  expect_equal(npz.read("u1"), at::tensor({255, 0}, at::kInt).to(at::kByte));
  expect_equal(npz.read("i1"), at::tensor({-128, 127}, at::kInt).to(at::kChar));
  expect_equal(npz.read("f2"), at::tensor({0.5, -2.0}, at::kFloat).to(at::kHalf));
  expect_equal(npz.read("scalar"), at::scalar_tensor(2.5, at::kDouble));
  expect_equal(npz.read("empty"), at::zeros({0, 3}, at::kFloat));
  EXPECT_TRUE(npz.contains("f4"));
  EXPECT_FALSE(npz.contains("f4.npy"));
}

TEST(Npz, ReadsDeflatedMembers) {
  ScratchFolder folder;
  const NpzArchive npz(numpy_archive(folder, kNumpyDeflated, kNumpyDeflatedSize, "numpy_deflated.npz"));
  expect_equal(npz.read("weights"), at::arange(24, at::kDouble).view({2, 3, 4}) / 8);
  expect_equal(npz.read("f"), at::tensor({0, 1, 2, 2, 1, 3}, at::kLong).view({2, 3}));
}

TEST(Npz, WritesWhatItReadsInBothCompressions) {
  ScratchFolder folder;
  const std::vector<std::pair<std::string, at::Tensor>> arrays = {
      {"double", at::randn({4, 5}, at::kDouble)},
      {"transposed", at::randn({3, 6}, at::kFloat).t()},  // written in C order
      {"long", at::arange(-5, 5, at::kLong).view({2, 5})},
      {"int", at::tensor({-1, 2}, at::kInt)},
      {"bytes", at::tensor({0, 200}, at::kInt).to(at::kByte)},
      {"bool", at::tensor({1, 0}, at::kInt).to(at::kBool)},
      {"half", at::tensor({0.25, 8.0}, at::kFloat).to(at::kHalf)},
      {"scalar", at::scalar_tensor(7.0, at::kDouble)},
      {"empty", at::zeros({0, 3}, at::kFloat)},
      {"many_dims", at::ones({1, 2, 1, 2, 1, 2, 1, 2, 1, 2}, at::kFloat)}};
  for (const auto compression : {io::NpzCompression::kStored, io::NpzCompression::kDeflate}) {
    const std::string path = folder.file(compression == io::NpzCompression::kStored ? "stored.npz" : "deflated.npz");
    io::write_npz(path, arrays, /*overwrite=*/false, compression);
    const NpzArchive npz(path);
    ASSERT_EQ(npz.keys().size(), arrays.size());
    for (const auto& [name, tensor] : arrays) expect_equal(npz.read(name), tensor.contiguous());
  }
  // Deflate shrinks a compressible array; storing does not.
  const std::vector<std::pair<std::string, at::Tensor>> zeros = {{"zeros", at::zeros({10000}, at::kDouble)}};
  io::write_npz(folder.file("z_stored.npz"), zeros, false, io::NpzCompression::kStored);
  io::write_npz(folder.file("z_deflated.npz"), zeros, false, io::NpzCompression::kDeflate);
  EXPECT_GT(std::filesystem::file_size(folder.file("z_stored.npz")), 80000u);
  EXPECT_LT(std::filesystem::file_size(folder.file("z_deflated.npz")), 2000u);
  // Equal arrays give equal files (fixed entry times), so written models can be compared by checksum.
  io::write_npz(folder.file("again.npz"), zeros, false, io::NpzCompression::kDeflate);
  EXPECT_EQ(read_bytes(folder.file("again.npz")), read_bytes(folder.file("z_deflated.npz")));

  const std::string npy = folder.file("single.npy");
  io::write_npy(npy, arrays[0].second, false);
  expect_equal(io::read_npy(npy), arrays[0].second);
}

TEST(Npz, HeadersAreByteIdenticalToNumpys) {
  // numpy.savez stores members verbatim, so numpy's own bytes for 'f4' appear inside the archive.
  ScratchFolder folder;
  const std::string path = folder.file("f4.npy");
  io::write_npy(path, at::tensor({1.5, -2.25, 3.0, 4.0, 5.5, -6.75}, at::kFloat).view({2, 3}), false);
  const std::vector<unsigned char> ours = read_bytes(path);
  const unsigned char* end = kNumpyStored + kNumpyStoredSize;
  EXPECT_NE(std::search(kNumpyStored, end, ours.begin(), ours.end()), end);
}

TEST(Npz, RefusesToOverwriteUnlessAsked) {
  ScratchFolder folder;
  const std::string path = folder.file("a.npz");
  io::write_npz(path, {{"a", at::zeros({2})}}, false);
  expect_error([&] { io::write_npz(path, {{"a", at::ones({2})}}, false); }, {"refusing to overwrite", path});
  io::write_npz(path, {{"a", at::ones({2})}}, true);
  EXPECT_TRUE(NpzArchive(path).read("a").equal(at::ones({2})));
  expect_error([&] { io::write_npz(folder.file("missing/b.npz"), {{"a", at::ones({2})}}, false); }, {"does not exist"});
  expect_error(
      [&] {
        io::write_npz(folder.file("c.npz"), {{"a", at::ones({2})}, {"a", at::ones({2})}}, false);
      },
      {"repeated"});
  expect_error(
      [&] {
        io::write_npz(folder.file("d.npz"), {{"c", at::ones({2}, at::kComplexFloat)}}, false);
      },
      {"cannot write array 'c'", "ComplexFloat"});
  EXPECT_FALSE(std::filesystem::exists(folder.file("d.npz")));
}

TEST(Npz, MissingOrForeignFilesAreClearErrors) {
  ScratchFolder folder;
  expect_error([&] { NpzArchive(folder.file("absent.npz")); }, {"absent.npz", "does not exist"});
  expect_error([&] { NpzArchive(folder.str()); }, {"not a regular file"});
  const std::string text = folder.file("model.pkl");
  write_bytes(text, "(dp0\nS'v_template'\n", 20);
  expect_error([&] { NpzArchive{text}; }, {"model.pkl", "is not an .npz archive", "convert_mano_pkl.py"});
  const std::string path = numpy_archive(folder, kNumpyDeflated, kNumpyDeflatedSize, "x.npz");
  expect_error([&] { NpzArchive(path).read("shapedirs"); }, {"x.npz", "has no array 'shapedirs'", "weights, f"});
  expect_error([&] { io::read_npy(folder.file("absent.npy")); }, {"absent.npy", "does not exist"});
}

TEST(Npz, BadHeadersAndUnsupportedDtypesAreClearErrors) {
  ScratchFolder folder;
  const std::vector<unsigned char> sixteen(16, 0);
  expect_error([&] { io::read_npy(raw_npy(folder, "{'descr': '<f8', 'shape': (2,), }", sixteen)); },
               {"raw.npy", "bad .npy header", "lacks"});
  expect_error(
      [&] { io::read_npy(raw_npy(folder, "{'descr': '<f8', 'fortran_order': Maybe, 'shape': (2,), }", sixteen)); },
      {"bad .npy header", "fortran_order"});
  expect_error(
      [&] { io::read_npy(raw_npy(folder, "{'descr': '<c16', 'fortran_order': False, 'shape': (1,), }", sixteen)); },
      {"dtype '<c16'", "not supported", "float16/32/64"});
  expect_error(
      [&] { io::read_npy(raw_npy(folder, "{'descr': '|O', 'fortran_order': False, 'shape': (2,), }", sixteen)); },
      {"Python objects", "convert_mano_pkl.py"});
  expect_error(
      [&] {
        io::read_npy(raw_npy(folder, "{'descr': [('a', '<f8')], 'fortran_order': False, 'shape': (2,), }", sixteen));
      },
      {"structured array"});
  expect_error(
      [&] { io::read_npy(raw_npy(folder, "{'descr': '<f8', 'fortran_order': False, 'shape': (4,), }", sixteen)); },
      {"holds 16 bytes of data", "needs 32", "truncated"});
  std::vector<unsigned char> huge(8, 0xff);
  huge[7] = 0x80;
  expect_error(
      [&] { io::read_npy(raw_npy(folder, "{'descr': '<u8', 'fortran_order': False, 'shape': (1,), }", huge)); },
      {"beyond the int64 range"});
  const std::string garbage = folder.file("garbage.npy");
  write_bytes(garbage, "not numpy at all", 16);
  expect_error([&] { io::read_npy(garbage); }, {"garbage.npy", "\\x93NUMPY magic"});
}

TEST(Npz, DamagedArchivesAreClearErrorsNotCrashes) {
  ScratchFolder folder;
  const at::Tensor values = at::arange(1000, at::kDouble);
  const std::string stored = folder.file("stored.npz");
  io::write_npz(stored, {{"values", values}}, false, io::NpzCompression::kStored);
  // Flip one data byte: the member's CRC no longer matches.
  std::vector<unsigned char> bytes = read_bytes(stored);
  const unsigned char* data = static_cast<const unsigned char*>(values.data_ptr());
  const auto at_data = std::search(bytes.begin(), bytes.end(), data + 800, data + 816);
  ASSERT_NE(at_data, bytes.end());
  *at_data ^= 0x5a;
  write_bytes(stored, bytes.data(), bytes.size());
  expect_error([&] { NpzArchive(stored).read("values"); }, {"stored.npz", "values", "damaged"});

  const std::string deflated = folder.file("deflated.npz");
  io::write_npz(deflated, {{"values", values}}, false, io::NpzCompression::kDeflate);
  bytes = read_bytes(deflated);
  for (size_t i = 60; i < 90; ++i) bytes[i] ^= 0xa5;  // inside the compressed stream
  write_bytes(deflated, bytes.data(), bytes.size());
  expect_error([&] { NpzArchive(deflated).read("values"); }, {"deflated.npz"});

  const std::string truncated = folder.file("truncated.npz");
  bytes = read_bytes(stored);
  write_bytes(truncated, bytes.data(), bytes.size() / 2);
  expect_error([&] { NpzArchive(truncated).read("values"); }, {"truncated.npz"});
}

}  // namespace
}  // namespace sfgs::testing
