// Weights files (nn/checkpoint_weights.h): the HDF5 checkpoint's model value for value, and one
// clear error naming the file and the field for every broken file.
#include <gtest/gtest.h>

#include "tests/support/file_bytes.h"

#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>

#include "../data/temp_dir.h"
#include "common/error.h"
#include "nn/checkpoint.h"
#include "nn/checkpoint_weights.h"
#include "nn/unet.h"

namespace fs = std::filesystem;
using namespace lidarsim;
using namespace lidarsim::nn;
using lidarsim::testing::error_of;

namespace {

using lidarsim::testing::read_bytes;
using lidarsim::testing::write_bytes;

// A model with every optional part (heads, per-row affine layer, lookup base), random values.
UNet full_model() {
  UNetConfig c{5, 2, 4, 2};
  c.heads = {HeadKind::mean, HeadKind::log_scale_laplace};
  c.row_affine_rows = 8;
  c.lookup = {3, 1, 0, 6, 0.25f, 8};
  UNet m(c);
  m.init(7);
  return m;
}

// The header's offset and length in a weights file (after the magic line).
std::pair<std::size_t, std::size_t> header_of(const std::string& bytes) {
  const std::size_t at = bytes.find('\n') + 1;
  std::uint64_t length = 0;
  std::memcpy(&length, bytes.data() + at, sizeof length);
  return {at + 8, static_cast<std::size_t>(length)};
}

// The file with its header text edited (the length field follows).
std::string with_header(std::string bytes, const std::string& from, const std::string& to) {
  auto [at, length] = header_of(bytes);
  std::string header = bytes.substr(at, length);
  const auto pos = header.find(from);
  EXPECT_NE(pos, std::string::npos) << from;
  header.replace(pos, from.size(), to);
  const std::uint64_t n = header.size();
  std::string out = bytes.substr(0, at - 8);
  out.append(reinterpret_cast<const char*>(&n), 8);
  return out + header + bytes.substr(at + length);
}

}  // namespace

TEST(CheckpointWeights, HoldTheCheckpointsModelValueForValue) {
  lidarsim::testing::TempDir dir;
  UNet model = full_model();
  Checkpoint meta;
  meta.attributes = {{"encoder", "{\"channels\": [1]}"}, {"beam_layout", "line1\nline2"}};
  save_checkpoint(dir / "m.h5", model, nullptr, meta);
  const Checkpoint read = read_checkpoint_meta(dir / "m.h5");
  UNet loaded(read.unet);
  load_checkpoint(dir / "m.h5", loaded, nullptr);
  save_weights(dir / "m.weights", loaded, read.attributes);

  EXPECT_TRUE(is_weights_file(dir / "m.weights"));
  EXPECT_FALSE(is_weights_file(dir / "m.h5"));
  const Weights w = read_weights(dir / "m.weights");
  EXPECT_EQ(w.model.config(), model.config());
  EXPECT_EQ(w.meta.unet, model.config());
  EXPECT_EQ(w.meta.attributes, meta.attributes);
  ASSERT_EQ(w.model.params().size(), model.params().size());
  EXPECT_EQ(std::memcmp(w.model.params().values(), model.params().values(), model.params().size() * sizeof(float)), 0);
  // Deterministic bytes: saving the read model again gives the same file.
  save_weights(dir / "again.weights", w.model, w.meta.attributes);
  EXPECT_EQ(read_bytes(dir / "again.weights"), read_bytes(dir / "m.weights"));
}

TEST(CheckpointWeights, BrokenFilesAreOneErrorNamingTheFileAndField) {
  lidarsim::testing::TempDir dir;
  const UNet model = full_model();
  const fs::path good = dir / "good.weights", bad = dir / "bad.weights";
  save_weights(good, model, {{"encoder", "{}"}});
  const std::string bytes = read_bytes(good);
  const auto [at, length] = header_of(bytes);
  auto error_for = [&](const std::string& broken) {
    write_bytes(bad, broken);
    return error_of([&] { read_weights(bad); });
  };
  const std::string file = bad.string() + ": ";

  EXPECT_EQ(error_of([&] { read_weights(good); }), "");
  EXPECT_EQ(error_for("\x89HDF\r\n\x1a\n" + bytes.substr(8)).rfind(file + "magic: not a lidarsim weights file", 0), 0u);
  EXPECT_EQ(error_for("lidarsim-weights 5" + bytes.substr(18)), file + "magic: \"lidarsim-weights 5\": this build reads formats 1 to 4");
  // Format 4 carries a zero head (and format 3's fields): without them the file is torn.
  EXPECT_EQ(error_for("lidarsim-weights 4" + bytes.substr(18)), file + "header.unet.spread_scale: missing");
  // Format 3 carries the spread residual table (and the factor): without them the file is torn.
  EXPECT_EQ(error_for("lidarsim-weights 3" + bytes.substr(18)), file + "header.unet.spread_scale: missing");
  // Format 2 carries the spread head's calibration factor: without it the file is torn.
  EXPECT_EQ(error_for("lidarsim-weights 2" + bytes.substr(18)), file + "header.unet.spread_scale: missing");
  EXPECT_EQ(error_for(bytes.substr(0, 22)).rfind(file + "header length: torn", 0), 0u);
  EXPECT_EQ(error_for(bytes.substr(0, at + length / 2)).rfind(file + "header length: ", 0), 0u);
  EXPECT_EQ(error_for(bytes.substr(0, bytes.size() - 4)).rfind(file + "values: ", 0), 0u);
  EXPECT_EQ(error_for(bytes + "x").rfind(file + "values: ", 0), 0u);
  std::string flipped = bytes;
  flipped[bytes.size() - 3] ^= 0x10;
  EXPECT_EQ(error_for(flipped).rfind(file + "values: checksum", 0), 0u);
  EXPECT_EQ(error_for(with_header(bytes, "\"base\":4", "\"base\":0")),
            file + "header.unet.base: expected an integer in [1, 2^20], got 0");
  EXPECT_EQ(error_for(with_header(bytes, "\"base\":4", "\"base\":\"4\"")),
            file + "header.unet.base: expected number, got string");
  EXPECT_EQ(error_for(with_header(bytes, "\"depth\":2,", "")), file + "header.unet.depth: missing");
  EXPECT_EQ(error_for(with_header(bytes, "mean,log_scale_laplace", "log_scale_laplace,mean")).rfind(file + "header.unet.heads: ", 0), 0u);
  const std::string header = bytes.substr(at, length);
  const std::size_t shape = header.find("\"shape\":[");
  const std::string first_shape = header.substr(shape, header.find(']', shape) + 1 - shape);
  EXPECT_EQ(error_for(with_header(bytes, first_shape, "\"shape\":[1,1,1,1]")), file + "header.params[0].shape: [1,1,1,1], the model expects " + first_shape.substr(8));
  EXPECT_EQ(error_for(with_header(bytes, "\"name\":\"", "\"name\":\"x")).rfind(file + "header.params[0].name: ", 0), 0u);
  EXPECT_EQ(error_for(with_header(bytes, "{", "[")), file + "header: not a JSON object");
  EXPECT_EQ(error_of([&] { read_weights(dir / "missing.weights"); }), (dir / "missing.weights").string() + ": file: cannot be opened");
}
