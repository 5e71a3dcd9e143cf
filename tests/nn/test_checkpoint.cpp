// Checkpoints: round trip, byte-identical saves, and clear errors for broken files.
#include <gtest/gtest.h>

#include "tests/support/file_bytes.h"
#include <hdf5.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <limits>
#include <random>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "common/error.h"
#include "nn/checkpoint.h"
#include "nn/checkpoint_image.h"
#include "nn/loss.h"
#include "nn/optim.h"
#include "nn/unet.h"

namespace fs = std::filesystem;
using namespace lidarsim;
using namespace lidarsim::nn;

namespace {

using lidarsim::testing::read_bytes;
using lidarsim::testing::write_bytes;

const UNetConfig kSmall{3, 1, 4, 2};

Tensor random_tensor(Shape s, std::uint32_t seed, float lo, float hi) {
  Tensor t(s);
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(lo, hi);
  for (float& x : t) x = u(rng);
  return t;
}

// Runs one Adam step so the optimizer state (m, v, steps) is non-trivial.
void train_one_step(UNet& model, Optimizer& opt) {
  const Tensor x = random_tensor({2, 3, 12, 20}, 1, -1.f, 1.f);
  const Tensor target = random_tensor({2, 1, 12, 20}, 2, 0.f, 1.f);
  Tensor mask = random_tensor({2, 1, 12, 20}, 3, 0.f, 1.f);
  for (float& m : mask) m = m < 0.7f ? 1.f : 0.f;
  Tensor y, dy;
  model.params().zero_grads();
  model.forward(x, y);
  dy.resize(y.shape());
  masked_mse(y, target, mask, &dy);
  l2_penalty(model.params(), 1e-3f, true);
  model.backward(dy);
  opt.step(model.params());
}

std::vector<float> arena_values(const UNet& model) {
  return {model.params().values(), model.params().values() + model.params().size()};
}

class CheckpointTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() /
           ("lidarsim_test_checkpoint_" + std::to_string(::getpid()) + "_" +
            ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }

  // A trained small model with optimizer state, saved to `name`.
  fs::path save_trained(const std::string& name) {
    UNet model(kSmall);
    model.init(7);
    Optimizer opt(OptimizerConfig{}, model.params().size());
    train_one_step(model, opt);
    const fs::path p = dir_ / name;
    save_checkpoint(p, model, &opt, meta());
    return p;
  }

  static Checkpoint meta() {
    Checkpoint m;
    m.unet = kSmall;
    m.attributes["encoder"] = R"({"channels": ["range", "class", "material"]})";
    m.attributes["lambda"] = "0.001";
    m.state.epoch = 3;
    m.state.step = 42;
    std::mt19937_64 rng(5);
    rng.discard(10);
    std::ostringstream s;
    s << rng;
    m.state.rng = s.str();
    return m;
  }

  // Expects load_checkpoint to throw a lidarsim::Error whose message contains every `needle`.
  static void expect_load_error(const fs::path& p, const std::vector<std::string>& needles) {
    UNet model(kSmall);
    Optimizer opt(OptimizerConfig{}, model.params().size());
    try {
      load_checkpoint(p, model, &opt);
      FAIL() << "load_checkpoint accepted " << p;
    } catch (const Error& e) {
      for (const auto& n : needles) EXPECT_NE(std::string(e.what()).find(n), std::string::npos) << e.what();
    }
  }

  fs::path dir_;
};

// Edits a saved checkpoint with the HDF5 C API: delete `path`, optionally write a new dataset there.
void replace_dataset(const fs::path& file, const std::string& path, const std::vector<hsize_t>* dims,
                     const std::vector<float>* values) {
  hid_t f = H5Fopen(file.c_str(), H5F_ACC_RDWR, H5P_DEFAULT);
  ASSERT_GE(f, 0);
  ASSERT_GE(H5Ldelete(f, path.c_str(), H5P_DEFAULT), 0);
  if (dims) {
    hid_t space = H5Screate_simple(static_cast<int>(dims->size()), dims->data(), nullptr);
    hid_t set = H5Dcreate2(f, path.c_str(), H5T_IEEE_F32LE, space, H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT);
    ASSERT_GE(set, 0);
    ASSERT_GE(H5Dwrite(set, H5T_NATIVE_FLOAT, H5S_ALL, H5S_ALL, H5P_DEFAULT, values->data()), 0);
    H5Dclose(set);
    H5Sclose(space);
  }
  H5Fclose(f);
}

}  // namespace

TEST_F(CheckpointTest, SaveThenLoadRestoresParametersOptimizerStateAndPredictions) {
  UNet model(kSmall);
  model.init(7);
  Optimizer opt(OptimizerConfig{}, model.params().size());
  train_one_step(model, opt);
  train_one_step(model, opt);
  const fs::path p = dir_ / "ckpt.h5";
  save_checkpoint(p, model, &opt, meta());

  UNet loaded(kSmall);
  loaded.init(99);  // different weights, so a no-op load would be caught
  Optimizer loaded_opt(OptimizerConfig{}, loaded.params().size());
  ASSERT_NE(arena_values(loaded), arena_values(model));
  load_checkpoint(p, loaded, &loaded_opt);

  EXPECT_EQ(arena_values(loaded), arena_values(model));
  EXPECT_EQ(loaded_opt.m(), opt.m());
  EXPECT_EQ(loaded_opt.v(), opt.v());
  EXPECT_EQ(loaded_opt.steps(), 2);

  const Tensor x = random_tensor({1, 3, 13, 21}, 11, -1.f, 1.f);
  Tensor y_model, y_loaded;
  model.predict(x, y_model);
  loaded.predict(x, y_loaded);
  ASSERT_EQ(y_model.shape(), y_loaded.shape());
  EXPECT_TRUE(std::equal(y_model.begin(), y_model.end(), y_loaded.begin()));

  // The next optimizer step continues identically from the loaded state.
  train_one_step(model, opt);
  train_one_step(loaded, loaded_opt);
  EXPECT_EQ(arena_values(loaded), arena_values(model));
}

TEST_F(CheckpointTest, MetaRoundTripsConfigAttributesStateAndOptimizerSettings) {
  const fs::path p = save_trained("ckpt.h5");
  const Checkpoint m = read_checkpoint_meta(p);
  const Checkpoint want = meta();
  EXPECT_EQ(m.unet, kSmall);
  EXPECT_EQ(m.attributes, want.attributes);
  EXPECT_EQ(m.state.epoch, 3);
  EXPECT_EQ(m.state.step, 42);
  EXPECT_EQ(m.state.rng, want.state.rng);
  ASSERT_TRUE(m.optimizer.has_value());
  EXPECT_EQ(m.optimizer->kind, OptimizerKind::Adam);
  EXPECT_FLOAT_EQ(m.optimizer->lr, OptimizerConfig{}.lr);
  EXPECT_FLOAT_EQ(m.optimizer->beta2, OptimizerConfig{}.beta2);
}

TEST_F(CheckpointTest, TwoSavesOfTheSameModelAreByteIdentical) {
  UNet model(kSmall);
  model.init(7);
  Optimizer opt(OptimizerConfig{}, model.params().size());
  train_one_step(model, opt);
  save_checkpoint(dir_ / "a.h5", model, &opt, meta());
  // HDF5 stamps objects with a time in seconds unless told not to: wait past a second boundary.
  std::this_thread::sleep_for(std::chrono::milliseconds(1100));
  save_checkpoint(dir_ / "b.h5", model, &opt, meta());
  const std::string a = read_bytes(dir_ / "a.h5"), b = read_bytes(dir_ / "b.h5");
  ASSERT_GT(a.size(), 1000u);
  EXPECT_TRUE(a == b) << "checkpoints of the same state differ";
}

TEST_F(CheckpointTest, DatasetsCarryLayerNamesAndPyTorchShapes) {
  const fs::path p = save_trained("ckpt.h5");
  hid_t f = H5Fopen(p.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  ASSERT_GE(f, 0);
  auto dims_of = [&](const char* path) {
    std::vector<hsize_t> dims;
    hid_t set = H5Dopen2(f, path, H5P_DEFAULT);
    if (set < 0) return dims;
    hid_t space = H5Dget_space(set);
    dims.resize(static_cast<std::size_t>(H5Sget_simple_extent_ndims(space)));
    H5Sget_simple_extent_dims(space, dims.data(), nullptr);
    H5Sclose(space);
    H5Dclose(set);
    return dims;
  };
  EXPECT_EQ(dims_of("/params/enc0.conv1/weight"), (std::vector<hsize_t>{4, 3, 3, 3}));
  EXPECT_EQ(dims_of("/params/enc0.conv1/bias"), (std::vector<hsize_t>{4}));
  EXPECT_EQ(dims_of("/params/dec1.up/weight"), (std::vector<hsize_t>{16, 8, 2, 2}));
  EXPECT_EQ(dims_of("/params/head/weight"), (std::vector<hsize_t>{1, 4, 1, 1}));
  EXPECT_EQ(dims_of("/optimizer/v/dec0.conv2/weight"), (std::vector<hsize_t>{4, 4, 3, 3}));
  H5Fclose(f);
}

TEST_F(CheckpointTest, SaveLeavesNoTemporaryFileBehind) {
  save_trained("ckpt.h5");
  std::vector<std::string> names;
  for (const auto& e : fs::directory_iterator(dir_)) names.push_back(e.path().filename().string());
  EXPECT_EQ(names, std::vector<std::string>{"ckpt.h5"});
}

TEST_F(CheckpointTest, TruncatedFileThrowsErrorNamingTheFile) {
  const fs::path p = save_trained("ckpt.h5");
  const std::string bytes = read_bytes(p);
  for (std::size_t keep : {std::size_t{0}, std::size_t{7}, std::size_t{600}, bytes.size() / 2, bytes.size() - 1}) {
    SCOPED_TRACE("kept " + std::to_string(keep) + " of " + std::to_string(bytes.size()) + " bytes");
    const fs::path cut = dir_ / "cut.h5";
    write_bytes(cut, bytes.substr(0, keep));
    expect_load_error(cut, {cut.string()});
    EXPECT_THROW(read_checkpoint_meta(cut), Error);
  }
}

TEST_F(CheckpointTest, GarbageAndMissingFilesThrowErrorNamingTheFile) {
  const fs::path garbage = dir_ / "garbage.h5";
  std::string junk(4096, '\0');
  std::mt19937 rng(1);
  for (char& c : junk) c = static_cast<char>(rng());
  write_bytes(garbage, junk);
  expect_load_error(garbage, {garbage.string()});
  expect_load_error(dir_ / "absent.h5", {(dir_ / "absent.h5").string(), "no such file"});
}

TEST_F(CheckpointTest, CorruptedBytesGiveAnErrorOrALoadButNeverACrash) {
  const fs::path p = save_trained("ckpt.h5");
  const std::string bytes = read_bytes(p);
  int errors = 0;
  for (std::size_t at = 0; at + 64 < bytes.size(); at += bytes.size() / 40) {
    std::string bad = bytes;
    for (std::size_t i = at; i < at + 64; ++i) bad[i] = static_cast<char>(0xA5);
    const fs::path q = dir_ / "bad.h5";
    write_bytes(q, bad);
    UNet model(kSmall);
    Optimizer opt(OptimizerConfig{}, model.params().size());
    try {
      load_checkpoint(q, model, &opt);
    } catch (const Error& e) {
      ++errors;
      EXPECT_NE(std::string(e.what()).find(q.string()), std::string::npos) << e.what();
    }
  }
  EXPECT_GT(errors, 0);  // corrupting the superblock at offset 0 must at least be caught
}

TEST_F(CheckpointTest, WrongShapedParameterNamesFileParameterAndShapes) {
  const fs::path p = save_trained("ckpt.h5");
  const std::vector<hsize_t> dims{4, 4, 5, 5};
  const std::vector<float> values(4 * 4 * 5 * 5, 0.5f);
  replace_dataset(p, "/params/enc0.conv2/weight", &dims, &values);
  expect_load_error(p, {p.string(), "params/enc0.conv2/weight", "[4, 4, 5, 5]", "[4, 4, 3, 3]"});
}

TEST_F(CheckpointTest, MissingParameterNamesFileAndParameter) {
  const fs::path p = save_trained("ckpt.h5");
  replace_dataset(p, "/params/dec0.up/bias", nullptr, nullptr);
  expect_load_error(p, {p.string(), "params/dec0.up/bias", "missing"});
}

TEST_F(CheckpointTest, MissingOptimizerMomentNamesFileAndParameter) {
  const fs::path p = save_trained("ckpt.h5");
  replace_dataset(p, "/optimizer/v/head/weight", nullptr, nullptr);
  expect_load_error(p, {p.string(), "optimizer/v/head/weight", "missing"});
  // Without an optimizer the parameters alone still load.
  UNet model(kSmall);
  EXPECT_NO_THROW(load_checkpoint(p, model, nullptr));
}

TEST_F(CheckpointTest, NonFiniteParameterIsAnError) {
  const fs::path p = save_trained("ckpt.h5");
  const std::vector<hsize_t> dims{4};
  const std::vector<float> values{0.f, std::numeric_limits<float>::quiet_NaN(), 0.f, 0.f};
  replace_dataset(p, "/params/enc0.conv1/bias", &dims, &values);
  expect_load_error(p, {p.string(), "params/enc0.conv1/bias", "not finite"});
}

TEST_F(CheckpointTest, ArchitectureMismatchNamesTheConfigField) {
  const fs::path p = save_trained("ckpt.h5");
  UNet wider(UNetConfig{3, 1, 8, 2});
  try {
    load_checkpoint(p, wider, nullptr);
    FAIL() << "a base-4 checkpoint loaded into a base-8 model";
  } catch (const Error& e) {
    const std::string msg = e.what();
    EXPECT_NE(msg.find(p.string()), std::string::npos) << msg;
    EXPECT_NE(msg.find("unet.base"), std::string::npos) << msg;
  }
}

TEST_F(CheckpointTest, FailedLoadLeavesTheModelUnchanged) {
  const fs::path p = save_trained("ckpt.h5");
  replace_dataset(p, "/params/head/bias", nullptr, nullptr);  // the last parameter: all others read first
  UNet model(kSmall);
  model.init(3);
  const std::vector<float> before = arena_values(model);
  EXPECT_THROW(load_checkpoint(p, model, nullptr), Error);
  EXPECT_EQ(arena_values(model), before);
}

TEST_F(CheckpointTest, ReservedAttributeNameIsRejectedWithoutTouchingTheOldFile) {
  const fs::path p = save_trained("ckpt.h5");
  const std::string before = read_bytes(p);
  UNet model(kSmall);
  Checkpoint m = meta();
  m.attributes["unet.base"] = "8";
  EXPECT_THROW(save_checkpoint(p, model, nullptr, m), Error);
  EXPECT_EQ(read_bytes(p), before);
}

TEST_F(CheckpointTest, SgdStateRoundTripsAndAKindMismatchIsNamed) {
  UNet model(kSmall);
  model.init(7);
  OptimizerConfig sgd_config;
  sgd_config.kind = OptimizerKind::Sgd;
  sgd_config.lr = 0.01f;
  Optimizer sgd(sgd_config, model.params().size());
  train_one_step(model, sgd);
  const fs::path p = dir_ / "sgd.h5";
  save_checkpoint(p, model, &sgd, meta());

  UNet loaded(kSmall);
  Optimizer loaded_sgd(sgd_config, loaded.params().size());
  load_checkpoint(p, loaded, &loaded_sgd);
  EXPECT_EQ(loaded_sgd.m(), sgd.m());
  EXPECT_EQ(read_checkpoint_meta(p).optimizer->kind, OptimizerKind::Sgd);

  Optimizer adam(OptimizerConfig{}, loaded.params().size());
  try {
    load_checkpoint(p, loaded, &adam);
    FAIL() << "an SGD state loaded into Adam";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("optimizer/kind"), std::string::npos) << e.what();
  }
}

TEST_F(CheckpointTest, HdfFileThatIsNotACheckpointNamesTheMissingAttribute) {
  // The PyTorch fixture is valid HDF5 with a /config group, but not a checkpoint.
  const fs::path other = fs::path(LIDARSIM_SOURCE_DIR) / "tests/fixtures/unet_small_torch.h5";
  ASSERT_TRUE(fs::exists(other));
  try {
    read_checkpoint_meta(other);
    FAIL() << "read a non-checkpoint as a checkpoint";
  } catch (const Error& e) {
    const std::string msg = e.what();
    EXPECT_NE(msg.find(other.string()), std::string::npos) << msg;
    EXPECT_NE(msg.find("config/unet.in_channels"), std::string::npos) << msg;
  }
}

// The per-row affine layer (nn/unet.h) travels with its row count; a model without it is saved
// with no such attribute, and a file without the attribute loads as a model without the layer.
TEST_F(CheckpointTest, RowAffineLayerRoundTripsWithItsRowCountAndPredictions) {
  const UNetConfig with_rows{3, 1, 4, 2, 12};
  UNet model(with_rows);
  model.init(7);
  Optimizer opt(OptimizerConfig{}, model.params().size());
  train_one_step(model, opt);  // 12-row inputs: moves the gains off 1 and the offsets off 0
  const ParamArena& a = model.params();
  EXPECT_NE(a.value(a.find("row_affine/gain"))[3], 1.f);
  const fs::path p = dir_ / "rows.h5";
  Checkpoint m = meta();
  m.unet = with_rows;
  save_checkpoint(p, model, &opt, m);
  EXPECT_EQ(read_checkpoint_meta(p).unet, with_rows);

  UNet loaded(with_rows);
  loaded.init(99);
  Optimizer loaded_opt(OptimizerConfig{}, loaded.params().size());
  load_checkpoint(p, loaded, &loaded_opt);
  EXPECT_EQ(arena_values(loaded), arena_values(model));
  const Tensor x = random_tensor({1, 3, 12, 21}, 11, -1.f, 1.f);
  Tensor y_model, y_loaded;
  model.predict(x, y_model);
  loaded.predict(x, y_loaded);
  EXPECT_TRUE(std::equal(y_model.begin(), y_model.end(), y_loaded.begin()));

  // A model without the layer refuses the file, naming the field.
  UNet plain(kSmall);
  try {
    load_checkpoint(p, plain, nullptr);
    FAIL() << "a row-affine checkpoint loaded into a model without the layer";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("unet.row_affine_rows"), std::string::npos) << e.what();
  }
}

TEST_F(CheckpointTest, LookupBaseRoundTripsWithItsTableSettingsAndPredictions) {
  const UNetConfig with_lookup{3, 1, 4, 2, 0, {2, 1, 0, 3, 0.3f, 12}};
  UNet model(with_lookup);
  model.init(7);
  ParamArena& a = model.params();
  const Tensor table = random_tensor({1, 1, 1, 9}, 31, 0.f, 1.f), beam = random_tensor({1, 1, 1, 12}, 32, -0.1f, 0.1f);
  std::copy(table.begin(), table.end(), a.value(a.find("lookup/table")));
  std::copy(beam.begin(), beam.end(), a.value(a.find("lookup/beam")));
  Optimizer opt(OptimizerConfig{}, a.size());
  train_one_step(model, opt);
  const fs::path p = dir_ / "lookup.h5";
  Checkpoint m = meta();
  m.unet = with_lookup;
  save_checkpoint(p, model, &opt, m);
  EXPECT_EQ(read_checkpoint_meta(p).unet, with_lookup);

  UNet loaded(with_lookup);
  loaded.init(99);
  load_checkpoint(p, loaded, nullptr);
  EXPECT_EQ(arena_values(loaded), arena_values(model));
  const Tensor x = random_tensor({1, 3, 12, 21}, 11, -1.f, 1.f);
  Tensor y_model, y_loaded;
  model.predict(x, y_model);
  loaded.predict(x, y_loaded);
  EXPECT_TRUE(std::equal(y_model.begin(), y_model.end(), y_loaded.begin()));

  // Another bin width, or no lookup base at all, refuses the file naming the field.
  for (const UNetConfig& other : {UNetConfig{3, 1, 4, 2, 0, {2, 1, 0, 3, 0.25f, 12}}, UNetConfig{3, 1, 4, 2}}) {
    UNet wrong(other);
    try {
      load_checkpoint(p, wrong, nullptr);
      FAIL() << "a lookup-base checkpoint loaded into a model with other settings";
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find("unet.lookup"), std::string::npos) << e.what();
    }
  }
}

TEST_F(CheckpointTest, ModelWithoutRowAffineIsSavedWithoutTheAttributeAndLoadsAsBefore) {
  const fs::path p = save_trained("plain.h5");
  hid_t f = H5Fopen(p.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  ASSERT_GE(f, 0);
  EXPECT_EQ(H5Aexists_by_name(f, "config", "unet.row_affine_rows", H5P_DEFAULT), 0);
  EXPECT_EQ(H5Aexists_by_name(f, "config", "unet.lookup.classes", H5P_DEFAULT), 0);
  EXPECT_EQ(H5Aexists_by_name(f, "config", "unet.depth", H5P_DEFAULT), 1);
  H5Fclose(f);
  EXPECT_EQ(read_checkpoint_meta(p).unet.row_affine_rows, 0);
  UNet model(kSmall);
  EXPECT_NO_THROW(load_checkpoint(p, model, nullptr));
  UNet with_rows(UNetConfig{3, 1, 4, 2, 12});
  EXPECT_THROW(load_checkpoint(p, with_rows, nullptr), Error);
}

// The in-memory overloads (the fuzz target's way in) run the same checks as the path ones.
TEST_F(CheckpointTest, AFileImageInMemoryLoadsAsTheFileDoesAndIsRejectedAsTheFileIsWhenCut) {
  const fs::path p = save_trained("ckpt.h5");
  const std::string bytes = read_bytes(p);
  const MemoryImage image{bytes.data(), bytes.size(), "in-memory.h5"};
  const Checkpoint from_file = read_checkpoint_meta(p), from_image = read_checkpoint_meta(image);
  EXPECT_EQ(from_image.unet, from_file.unet);
  EXPECT_EQ(from_image.attributes, from_file.attributes);
  EXPECT_EQ(from_image.state.rng, from_file.state.rng);
  UNet a(kSmall), b(kSmall);
  a.init(1);
  b.init(2);
  Optimizer oa(OptimizerConfig{}, a.params().size()), ob(OptimizerConfig{}, b.params().size());
  load_checkpoint(p, a, &oa);
  load_checkpoint(image, b, &ob);
  EXPECT_EQ(arena_values(a), arena_values(b));
  EXPECT_EQ(oa.m(), ob.m());
  EXPECT_EQ(oa.steps(), ob.steps());

  for (std::size_t keep : {std::size_t{0}, std::size_t{7}, bytes.size() / 2, bytes.size() - 1}) {
    SCOPED_TRACE("kept " + std::to_string(keep) + " of " + std::to_string(bytes.size()) + " bytes");
    const MemoryImage cut{bytes.data(), keep, "cut-in-memory.h5"};
    try {
      load_checkpoint(cut, b, &ob);
      FAIL() << "a cut image was accepted";
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find("cut-in-memory.h5"), std::string::npos) << e.what();
    }
  }
  EXPECT_FALSE(fs::exists("cut-in-memory.h5"));  // the name only labels the image
}
