// Atomic writes on a full disk: an error, and the previous file stays as it was.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <iterator>

#include "common/atomic_file.h"
#include "common/error.h"
#include "tests/support/file_limit.h"

namespace fs = std::filesystem;
using namespace lidarsim;

namespace {

std::string read_text(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

fs::path fresh_dir(const std::string& name) {
  const fs::path dir = fs::temp_directory_path() / ("lidarsim_rel_common_" + name + "_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir;
}

}  // namespace

TEST(AtomicFileReliability, SmallWriteOnAFullDiskThrowsAndKeepsThePreviousFile) {
  const fs::path dir = fresh_dir("small");
  const fs::path file = dir / "log.csv";
  write_file_atomically(file, "epoch,loss\n1,0.5\n");
  // A few bytes stay in the stream's buffer until close: the close is where the disk is full.
  const std::string status = lidarsim::testing::run_with_file_size_limit(0, [&] {
    try {
      write_file_atomically(file, "epoch,loss\n1,0.5\n2,0.4\n");
    } catch (const Error&) {
      return 3;
    }
    return 0;
  });
  EXPECT_EQ(status, "exit 3") << "the write on a full disk must throw lidarsim::Error";
  EXPECT_EQ(read_text(file), "epoch,loss\n1,0.5\n");
  fs::remove_all(dir);
}

TEST(AtomicFileReliability, LargeWriteOnAFullDiskThrowsAndLeavesNoTemporary) {
  const fs::path dir = fresh_dir("large");
  const fs::path file = dir / "cloud.pcd";
  const std::string status = lidarsim::testing::run_with_file_size_limit(4096, [&] {
    try {
      write_file_atomically(file, std::string(1 << 20, 'x'));
    } catch (const Error&) {
      return 3;
    }
    return 0;
  });
  EXPECT_EQ(status, "exit 3");
  EXPECT_FALSE(fs::exists(file));
  for (const auto& e : fs::directory_iterator(dir)) ADD_FAILURE() << "left behind: " << e.path();
  fs::remove_all(dir);
}
