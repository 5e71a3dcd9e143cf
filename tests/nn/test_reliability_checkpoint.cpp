// Checkpoints under stress: a full disk during the save, and bit flips in the saved file.
#include <gtest/gtest.h>

#include "tests/support/file_bytes.h"
#include <unistd.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

#include "common/error.h"
#include "nn/checkpoint.h"
#include "nn/optim.h"
#include "nn/unet.h"
#include "tests/support/file_limit.h"

namespace fs = std::filesystem;
using namespace lidarsim;
using namespace lidarsim::nn;

namespace {

using lidarsim::testing::read_bytes;
using lidarsim::testing::write_bytes;

fs::path fresh_dir(const std::string& name) {
  const fs::path dir = fs::temp_directory_path() / ("lidarsim_rel_nn_" + name + "_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir;
}

Checkpoint meta_for(std::int64_t step) {
  Checkpoint meta;
  meta.attributes["encoder"] = "{\"channels\": [\"range\"]}";
  meta.state.step = step;
  meta.state.rng = "counter-based";
  return meta;
}

}  // namespace

TEST(CheckpointReliability, SaveOnAFullDiskThrowsExitsCleanlyAndKeepsThePreviousCheckpoint) {
  const fs::path dir = fresh_dir("full");
  const fs::path path = dir / "ck.h5";
  UNet model({3, 1, 8, 2});
  model.init(1);
  Optimizer opt(OptimizerConfig{}, model.params().size());
  save_checkpoint(path, model, &opt, meta_for(1));
  const std::string before = read_bytes(path);
  model.init(2);
  // The child ends with std::exit: HDF5's exit handler runs over whatever the failed save left.
  const std::string status = lidarsim::testing::run_with_file_size_limit(8192, [&] {
    try {
      save_checkpoint(path, model, &opt, meta_for(2));
    } catch (const Error&) {
      return 3;
    }
    return 0;
  });
  EXPECT_EQ(status, "exit 3") << "one lidarsim::Error, then a clean exit";
  EXPECT_EQ(read_bytes(path), before) << "the previous checkpoint must stay intact";
  for (const auto& e : fs::directory_iterator(dir))
    if (e.path() != path) ADD_FAILURE() << "left behind: " << e.path();
  fs::remove_all(dir);
}

TEST(CheckpointReliability, NoSingleBitFlipLoadsChangedWeights) {
  const fs::path dir = fresh_dir("flip");
  const fs::path path = dir / "ck.h5", copy = dir / "flipped.h5";
  UNet model({2, 1, 2, 1});
  model.init(5);
  Optimizer opt(OptimizerConfig{}, model.params().size());
  save_checkpoint(path, model, &opt, meta_for(3));
  const std::string bytes = read_bytes(path);
  const std::vector<float> want(model.params().values(), model.params().values() + model.params().size());
  int accepted = 0, changed = 0, tried = 0;
  // About 1,500 offsets spread over the whole file (headers, checksums and data alike).
  const std::size_t stride = std::max<std::size_t>(1, bytes.size() / 1500);
  for (std::size_t at = 0; at < bytes.size(); at += stride) {
    std::string flipped = bytes;
    flipped[at] = static_cast<char>(flipped[at] ^ (1 << (at % 8)));
    write_bytes(copy, flipped);
    ++tried;
    UNet loaded({2, 1, 2, 1});
    Optimizer lopt(OptimizerConfig{}, loaded.params().size());
    try {
      (void)read_checkpoint_meta(copy);
      load_checkpoint(copy, loaded, &lopt);
    } catch (const Error&) {
      continue;
    }
    ++accepted;
    const std::vector<float> got(loaded.params().values(), loaded.params().values() + loaded.params().size());
    if (got != want || lopt.m() != opt.m() || lopt.v() != opt.v()) ++changed;
  }
  std::printf("%d flips: %d accepted, %d of them with changed values\n", tried, accepted, changed);
  EXPECT_EQ(changed, 0) << "a corrupted checkpoint loaded with different weights or optimizer state";
  fs::remove_all(dir);
}
