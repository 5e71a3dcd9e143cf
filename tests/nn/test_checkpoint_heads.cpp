// Checkpoint formats (nn/checkpoint.h): a model with several outputs or named heads is written as
// format 2 without `unet.out_channels`, the attribute every older build requires, so those builds
// refuse it by name; a one-output model is still format 1 as before, and files written by older
// builds (the shipped model) load. Unknown or newer formats are refused naming config/format.
#include <gtest/gtest.h>

#include "tests/support/file_bytes.h"
#include <hdf5.h>
#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <functional>
#include <optional>
#include <iterator>
#include <random>
#include <string>
#include <vector>

#include "common/error.h"
#include "nn/checkpoint.h"
#include "nn/heads.h"
#include "nn/optim.h"
#include "nn/unet.h"
#include "tests/support/shared_data.h"

namespace fs = std::filesystem;
using namespace lidarsim;
using namespace lidarsim::nn;

namespace {

using lidarsim::testing::read_bytes;

const std::vector<HeadKind> kThree{HeadKind::mean, HeadKind::return_logit, HeadKind::log_scale_laplace};
const UNetConfig kHeads{3, 3, 4, 2, 0, {}, kThree};
const UNetConfig kOne{3, 1, 4, 2};

Tensor input(int channels) {
  Tensor t(Shape{1, channels, 8, 12});
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> u(-1.f, 1.f);
  for (float& v : t) v = u(rng);
  return t;
}

bool has_attr(const fs::path& p, const std::string& name) {
  const hid_t f = H5Fopen(p.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  const bool yes = f >= 0 && H5Aexists_by_name(f, "config", name.c_str(), H5P_DEFAULT) > 0;
  if (f >= 0) H5Fclose(f);
  return yes;
}

std::string string_attr(const fs::path& p, const std::string& name) {
  std::string out;
  const hid_t f = H5Fopen(p.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  const hid_t a = H5Aopen_by_name(f, "config", name.c_str(), H5P_DEFAULT, H5P_DEFAULT);
  if (a >= 0) {
    const hid_t type = H5Aget_type(a);
    out.assign(H5Tget_size(type), '\0');
    H5Aread(a, type, out.data());
    out.resize(out.find('\0') == std::string::npos ? out.size() : out.find('\0'));
    H5Tclose(type);
    H5Aclose(a);
  }
  if (f >= 0) H5Fclose(f);
  return out;
}

// Replaces (or adds) a string attribute of /config with the HDF5 C API.
void set_string_attr(const fs::path& p, const std::string& name, const std::string& value) {
  const hid_t f = H5Fopen(p.c_str(), H5F_ACC_RDWR, H5P_DEFAULT);
  ASSERT_GE(f, 0);
  if (H5Aexists_by_name(f, "config", name.c_str(), H5P_DEFAULT) > 0) H5Adelete_by_name(f, "config", name.c_str(), H5P_DEFAULT);
  const hid_t type = H5Tcopy(H5T_C_S1);
  H5Tset_size(type, value.size());
  const hid_t space = H5Screate(H5S_SCALAR);
  const hid_t g = H5Gopen2(f, "config", H5P_DEFAULT);
  const hid_t a = H5Acreate2(g, name.c_str(), type, space, H5P_DEFAULT, H5P_DEFAULT);
  ASSERT_GE(a, 0);
  H5Awrite(a, type, value.data());
  H5Aclose(a);
  H5Gclose(g);
  H5Sclose(space);
  H5Tclose(type);
  H5Fclose(f);
}

std::string error_of(const std::function<void()>& f) {
  try {
    f();
  } catch (const Error& e) {
    return e.what();
  }
  return "no error";
}

class CheckpointHeadsTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("lidarsim_test_checkpoint_heads_" + std::to_string(::getpid()) + "_" +
                                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }

  fs::path save(const UNetConfig& cfg, const std::string& name, std::uint64_t seed = 7) {
    UNet model(cfg);
    model.init(seed);
    Optimizer opt(OptimizerConfig{}, model.params().size());
    Checkpoint meta;
    meta.attributes["encoder"] = "{}";
    meta.state.rng = "rng";
    const fs::path p = dir_ / name;
    save_checkpoint(p, model, &opt, meta);
    return p;
  }
  fs::path dir_;
};

TEST_F(CheckpointHeadsTest, ThreeHeadsAreFormat2WithoutOutChannelsAndRoundTripWithPredictions) {
  const fs::path p = save(kHeads, "heads.h5");
  EXPECT_EQ(string_attr(p, "format"), "lidarsim-checkpoint 2");
  EXPECT_FALSE(has_attr(p, "unet.out_channels")) << "older builds must find no unet.out_channels";
  EXPECT_TRUE(has_attr(p, "unet.outputs"));
  EXPECT_EQ(string_attr(p, "unet.heads"), "mean,return_logit,log_scale_laplace");

  const Checkpoint meta = read_checkpoint_meta(p);
  EXPECT_EQ(meta.unet, kHeads);
  UNet saved(kHeads), loaded(meta.unet);
  saved.init(7);
  loaded.init(99);
  Optimizer opt(OptimizerConfig{}, loaded.params().size());
  load_checkpoint(p, loaded, &opt);
  Tensor a, b;
  const Tensor x = input(3);
  saved.predict(x, a);
  loaded.predict(x, b);
  ASSERT_EQ(a.shape(), (Shape{1, 3, 8, 12}));
  EXPECT_EQ(std::vector<float>(a.begin(), a.end()), std::vector<float>(b.begin(), b.end()));
}

TEST_F(CheckpointHeadsTest, SeveralOutputsWithoutNamedHeadsAreFormat2Too) {
  const UNetConfig two{3, 2, 4, 2};
  const fs::path p = save(two, "two.h5");
  EXPECT_EQ(string_attr(p, "format"), "lidarsim-checkpoint 2");
  EXPECT_FALSE(has_attr(p, "unet.out_channels"));
  EXPECT_FALSE(has_attr(p, "unet.heads"));
  EXPECT_EQ(read_checkpoint_meta(p).unet, two);
}

TEST_F(CheckpointHeadsTest, OneOutputIsStillFormat1WithOutChannelsAndNoNewAttributes) {
  const fs::path p = save(kOne, "one.h5");
  EXPECT_EQ(string_attr(p, "format"), "lidarsim-checkpoint 1");
  EXPECT_TRUE(has_attr(p, "unet.out_channels"));
  EXPECT_FALSE(has_attr(p, "unet.outputs"));
  EXPECT_FALSE(has_attr(p, "unet.heads"));
  EXPECT_EQ(read_checkpoint_meta(p).unet, kOne);
  // One named head is a new field: format 2.
  const fs::path named = save(UNetConfig{3, 1, 4, 2, 0, {}, {HeadKind::mean}}, "named.h5");
  EXPECT_EQ(string_attr(named, "format"), "lidarsim-checkpoint 2");
}

// Files written by builds that predate format 2 load: the shipped model, and a small checkpoint
// written by such a build (tests/fixtures/make_format1_fixture.sh, from commit d989f80's nn/),
// which this build also writes again byte for byte: format 1 is unchanged.
TEST_F(CheckpointHeadsTest, CheckpointsFromAnOlderBuildLoadAndFormat1IsWrittenByteForByteAsBefore) {
  const fs::path shipped = lidarsim::testing::source_dir() / "data/models/intensity_unet.h5";
  ASSERT_TRUE(fs::exists(shipped)) << shipped;
  const Checkpoint meta = read_checkpoint_meta(shipped);
  EXPECT_EQ(meta.unet.out_channels, 1);
  EXPECT_TRUE(meta.unet.heads.empty());
  UNet model(meta.unet);
  EXPECT_NO_THROW(load_checkpoint(shipped, model, nullptr));

  const fs::path old = lidarsim::testing::source_dir() / "tests/fixtures/checkpoint_format1_small.h5";
  ASSERT_TRUE(fs::exists(old)) << old;
  const Checkpoint old_meta = read_checkpoint_meta(old);
  EXPECT_EQ(old_meta.unet, kOne);
  ASSERT_TRUE(old_meta.optimizer.has_value());
  UNet small(old_meta.unet);
  Optimizer opt(*old_meta.optimizer, small.params().size());
  load_checkpoint(old, small, &opt);
  EXPECT_EQ(opt.steps(), 1);
  const fs::path again = dir_ / "again.h5";
  save_checkpoint(again, small, &opt, old_meta);
  EXPECT_TRUE(read_bytes(again) == read_bytes(old)) << "format 1 is no longer written as the older build wrote it";
}

TEST_F(CheckpointHeadsTest, ANewerOrUnknownFormatIsRefusedNamingTheField) {
  const fs::path p = save(kHeads, "newer.h5");
  set_string_attr(p, "format", "lidarsim-checkpoint 6");
  const std::string e = error_of([&] { read_checkpoint_meta(p); });
  EXPECT_NE(e.find(p.string() + ": config/format: \"lidarsim-checkpoint 6\": this build reads formats 1 to 5"),
            std::string::npos)
      << e;
  EXPECT_NE(e.find("newer lidarsim"), std::string::npos) << e;
  set_string_attr(p, "format", "something else");
  EXPECT_NE(error_of([&] { read_checkpoint_meta(p); }).find("config/format: \"something else\" is not a lidarsim checkpoint format"),
            std::string::npos);
  UNet model(kHeads);
  EXPECT_NE(error_of([&] { load_checkpoint(p, model, nullptr); }).find("config/format"), std::string::npos);
}

TEST_F(CheckpointHeadsTest, OtherHeadsOrOutputCountsAndBadHeadTextAreRefusedNamingTheField) {
  const fs::path p = save(kHeads, "heads.h5");
  UNet gaussian(UNetConfig{3, 3, 4, 2, 0, {}, {HeadKind::mean, HeadKind::return_logit, HeadKind::log_scale_gaussian}});
  std::string e = error_of([&] { load_checkpoint(p, gaussian, nullptr); });
  EXPECT_NE(e.find("config/unet.heads: checkpoint has \"mean,return_logit,log_scale_laplace\""), std::string::npos) << e;
  UNet two(UNetConfig{3, 2, 4, 2, 0, {}, {HeadKind::mean, HeadKind::return_logit}});
  e = error_of([&] { load_checkpoint(p, two, nullptr); });
  EXPECT_NE(e.find("config/unet.outputs: checkpoint has 3, the model expects 2"), std::string::npos) << e;
  UNet one(kOne);
  EXPECT_NE(error_of([&] { load_checkpoint(p, one, nullptr); }).find("config/unet.outputs"), std::string::npos);

  set_string_attr(p, "unet.heads", "mean,return_logit,quantile");
  e = error_of([&] { read_checkpoint_meta(p); });
  EXPECT_NE(e.find("config/unet.heads: value: unknown head \"quantile\""), std::string::npos) << e;
  set_string_attr(p, "unet.heads", "return_logit,mean,log_scale_laplace");
  EXPECT_NE(error_of([&] { read_checkpoint_meta(p); }).find("channel 0 must be the mean"), std::string::npos);

  const fs::path old = save(kOne, "one.h5");
  set_string_attr(old, "unet.heads", "mean");
  EXPECT_NE(error_of([&] { read_checkpoint_meta(old); }).find("config/unet.heads: present in a format-1 checkpoint"),
            std::string::npos);
}

}  // namespace

// The spread head's calibration factor (UNetConfig::spread_scale) makes a format-3 checkpoint and a
// format-2 weights file, which builds that read formats 1-2 (resp. 1) refuse by their format
// number instead of sampling with the uncalibrated scale; a factor of 1 writes no trace of it, and
// format-2 files (every checkpoint before the factor) load with factor 1.
TEST_F(CheckpointHeadsTest, ASpreadCalibrationIsFormat3AndOlderFilesLoadWithFactor1) {
  const fs::path plain = save(kHeads, "plain.h5");
  EXPECT_EQ(string_attr(plain, "format"), "lidarsim-checkpoint 2");
  EXPECT_FALSE(has_attr(plain, "unet.spread_scale"));
  EXPECT_EQ(read_checkpoint_meta(plain).unet.spread_scale, 1.f);

  UNet model(kHeads);
  model.init(7);
  model.set_spread_scale(1.75f);
  Checkpoint meta;
  meta.attributes["encoder"] = "{}";
  const fs::path p = dir_ / "calibrated.h5";
  save_checkpoint(p, model, nullptr, meta);
  EXPECT_EQ(string_attr(p, "format"), "lidarsim-checkpoint 3");
  const Checkpoint back = read_checkpoint_meta(p);
  EXPECT_EQ(back.unet.spread_scale, 1.75f);
  EXPECT_EQ(back.unet, model.config());
  // The factor scales the head's output at inference: spread_scale * exp(clamp(s)).
  Tensor y(Shape{1, 3, 1, 2});
  y.channel(0, 2)[0] = 0.f, y.channel(0, 2)[1] = 10.f;
  heads_output_transform(y, kThree, {}, back.unet.spread_scale);
  EXPECT_FLOAT_EQ(y.channel(0, 2)[0], 1.75f);
  EXPECT_FLOAT_EQ(y.channel(0, 2)[1], 1.75f * std::exp(3.f));
  // The factor where format 2 has none, or a bad factor, is refused naming the field.
  set_string_attr(p, "format", "lidarsim-checkpoint 2");
  EXPECT_NE(error_of([&] { read_checkpoint_meta(p); }).find("config/unet.spread_scale: present in a format-2 checkpoint"),
            std::string::npos);
  const fs::path three_heads_format3 = save(kHeads, "no_factor.h5");
  set_string_attr(three_heads_format3, "format", "lidarsim-checkpoint 3");
  EXPECT_NE(error_of([&] { read_checkpoint_meta(three_heads_format3); }).find("unet.spread_scale"), std::string::npos);
  // No spread head: no factor.
  EXPECT_THROW(UNet(UNetConfig{3, 1, 4, 2, 0, {}, {}, 2.f}), Error);
}

// A zero head (nn/heads.h zero_logit) is format 5: format 4's fields (a factor of 1 and an empty
// table written too) and the head. A build that reads formats 1-4 refuses it by its number
// ("lidarsim-checkpoint 5": the refusal above, one format up); a zero head under a lower number is
// refused naming the field, and files of formats 1-4 still load (the tests above).
TEST_F(CheckpointHeadsTest, AZeroHeadIsFormat5AndOlderNumbersCannotCarryIt) {
  const UNetConfig zero{3, 3, 4, 2, 0, {}, {HeadKind::mean, HeadKind::log_scale_laplace, HeadKind::zero_logit}};
  const fs::path p = save(zero, "zero.h5");
  EXPECT_EQ(string_attr(p, "format"), "lidarsim-checkpoint 5");
  EXPECT_TRUE(has_attr(p, "unet.spread_scale"));
  EXPECT_TRUE(has_attr(p, "unet.spread_residual"));
  const Checkpoint back = read_checkpoint_meta(p);
  EXPECT_EQ(back.unet, zero);
  UNet model(zero);
  EXPECT_NO_THROW(load_checkpoint(p, model, nullptr));
  set_string_attr(p, "format", "lidarsim-checkpoint 4");
  const std::string e = error_of([&] { read_checkpoint_meta(p); });
  EXPECT_NE(e.find("config/unet.heads: a zero_logit head in a format-4 checkpoint (format 5 carries it)"), std::string::npos) << e;
  const fs::path no_zero = save(kHeads, "no_zero.h5");
  set_string_attr(no_zero, "format", "lidarsim-checkpoint 5");
  EXPECT_NE(error_of([&] { read_checkpoint_meta(no_zero); }).find("config/unet.heads: format 5, but no zero_logit head"),
            std::string::npos);
}
