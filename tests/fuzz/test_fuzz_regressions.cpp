// Replays every input the fuzzers ever flagged (fuzz/regressions/<target>/) through its target:
// each must now end in acceptance or one lidarsim::Error, never a crash or another exception.
#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

#include "fuzz/readers.h"
#include "tests/support/shared_data.h"

namespace fs = std::filesystem;

namespace {

std::vector<std::string> listed_targets() {
  std::ifstream in(lidarsim::testing::source_dir() / "fuzz/targets.txt");
  std::vector<std::string> names;
  for (std::string line; std::getline(in, line);)
    if (!line.empty()) names.push_back(line);
  return names;
}

}  // namespace

TEST(FuzzRegressions, EveryListedTargetExistsAndEveryTargetIsListed) {
  const auto listed = listed_targets();
  ASSERT_FALSE(listed.empty());
  for (const auto& name : listed) EXPECT_NE(lidarsim::fuzz::find_target(name), nullptr) << name;
  for (const auto& t : lidarsim::fuzz::targets())
    EXPECT_NE(std::find(listed.begin(), listed.end(), t.name), listed.end()) << t.name << " missing in targets.txt";
}

TEST(FuzzRegressions, EveryRecordedFindingIsNowRejectedCleanly) {
  int replayed = 0;
  for (const auto& t : lidarsim::fuzz::targets()) {
    const fs::path dir = lidarsim::testing::source_dir() / "fuzz/regressions" / t.name;
    if (!fs::is_directory(dir)) continue;
    for (const auto& e : fs::directory_iterator(dir)) {
      if (!e.is_regular_file()) continue;
      std::ifstream in(e.path(), std::ios::binary);
      const std::string bytes{std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
      EXPECT_NO_THROW(t.run(reinterpret_cast<const std::uint8_t*>(bytes.data()), bytes.size())) << e.path();
      ++replayed;
    }
  }
  std::printf("replayed %d recorded inputs\n", replayed);
  EXPECT_GT(replayed, 0) << "fuzz/regressions/ holds the inputs of defects found by fuzzing, each fixed";
}
