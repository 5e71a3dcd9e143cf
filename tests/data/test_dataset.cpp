#include <gtest/gtest.h>
#include <hdf5.h>

#include <cmath>

#include "common/error.h"
#include "data/dataset.h"
#include "pgm/projection.h"
#include "tests/data/temp_dir.h"

using namespace lidarsim;
using lidarsim::testing::TempDir;
using lidarsim::testing::error_of;

namespace {
data::Dataset two_frames() {
  const auto layout = pgm::BeamLayout::uniform(4, 2, -2, 32);
  data::Dataset d;
  d.channels = {"range", "class", "material"};
  d.source_format = "test";
  for (int f = 0; f < 2; ++f) {
    pgm::Point p;
    p.x = 5.f + f, p.y = 1, p.z = 0, p.intensity = 0.25f * (f + 1), p.class_id = 9, p.material_id = 1;
    pgm::ProjectOptions o;
    o.row_mode = pgm::RowMode::NearestElevation;
    const auto res = pgm::project({p}, layout, o);
    d.append(res.pgm, "f" + std::to_string(f), pgm::to_string(res.row_mode));
  }
  d.sources = {"a.bin", "b.bin"};
  return d;
}
}  // namespace

TEST(Dataset, WriteThenReadGivesTheSameTensorsAndAttributes) {
  TempDir dir;
  const auto d = two_frames();
  data::write_dataset(dir / "d.h5", d);
  const auto r = data::read_dataset(dir / "d.h5", {"range", "class"});
  EXPECT_EQ(r.size(), 2);
  EXPECT_EQ(r.channels, d.channels);
  EXPECT_EQ(r.frames, d.frames);
  EXPECT_EQ(r.sources, d.sources);
  EXPECT_EQ(r.row_modes, d.row_modes);
  EXPECT_EQ(r.layout.rows(), 4);
  EXPECT_EQ(r.layout.columns, 32);
  EXPECT_EQ(r.source_format, "test");
  ASSERT_EQ(r.pgm.shape(), d.pgm.shape());
  EXPECT_TRUE(std::equal(r.pgm.begin(), r.pgm.end(), d.pgm.begin()));
  EXPECT_TRUE(std::equal(r.target.begin(), r.target.end(), d.target.begin()));
  EXPECT_TRUE(std::equal(r.mask.begin(), r.mask.end(), d.mask.begin()));
  EXPECT_EQ(r.point_index, d.point_index);
  float mask_sum = 0;
  for (float m : r.mask.begin() == nullptr ? std::vector<float>{} : std::vector<float>(r.mask.begin(), r.mask.end())) mask_sum += m;
  EXPECT_EQ(mask_sum, 2.f);  // one return per frame
  const auto frame = r.frame_pgm(1);
  const int cell = static_cast<int>(std::find(frame.point_index().begin(), frame.point_index().end(), 0) - frame.point_index().begin());
  EXPECT_FLOAT_EQ(frame.channel("intensity")[cell], 0.5f);
  EXPECT_FLOAT_EQ(frame.channel("class")[cell], 9.f);
}

TEST(Dataset, MissingChannelIsNamedWithTheFile) {
  TempDir dir;
  data::write_dataset(dir / "d.h5", two_frames());
  const std::string msg = error_of([&] { data::read_dataset(dir / "d.h5", {"range", "incidence"}); });
  EXPECT_NE(msg.find("d.h5: /pgm channel 'incidence': missing"), std::string::npos) << msg;
}

TEST(Dataset, MissingDatasetIsNamedWithTheFile) {
  TempDir dir;
  for (const char* name : {"/mask", "/target", "/pgm", "/frames"}) {
    data::write_dataset(dir / "d.h5", two_frames());
    hid_t f = H5Fopen((dir / "d.h5").c_str(), H5F_ACC_RDWR, H5P_DEFAULT);
    ASSERT_GE(f, 0);
    ASSERT_GE(H5Ldelete(f, name, H5P_DEFAULT), 0);
    H5Fclose(f);
    const std::string msg = error_of([&] { data::read_dataset(dir / "d.h5"); });
    EXPECT_NE(msg.find("d.h5: dataset " + std::string(name) + ": missing"), std::string::npos) << msg;
  }
}

TEST(Dataset, WrongShapeAndNonHdf5FileAreErrors) {
  TempDir dir;
  { std::ofstream(dir / "x.h5") << "not hdf5"; }
  EXPECT_NE(error_of([&] { data::read_dataset(dir / "x.h5"); }).find("not an HDF5 file"), std::string::npos);
  auto d = two_frames();
  d.layout = pgm::BeamLayout::uniform(5, 2, -2, 32);  // attribute says 5 rows, /pgm has 4
  data::write_dataset(dir / "d.h5", d);
  const std::string msg = error_of([&] { data::read_dataset(dir / "d.h5"); });
  EXPECT_NE(msg.find("dataset /pgm: shape"), std::string::npos) << msg;
}

TEST(Dataset, FailedWriteLeavesNoFileBehind) {
  TempDir dir;
  auto d = two_frames();
  d.frames.pop_back();  // inconsistent: refused before anything is written
  EXPECT_THROW(data::write_dataset(dir / "d.h5", d), Error);
  EXPECT_FALSE(std::filesystem::exists(dir / "d.h5"));
}

TEST(Dataset, EncodeInputsRunsEveryFrameThroughTheEncoderAndNamesMissingChannels) {
  const auto d = two_frames();
  pgm::EncoderConfig cfg;
  cfg.channels = {"range", "class"};
  cfg.range_max_m = 10;
  const auto in = data::encode_inputs(d, cfg, "d.h5");
  ASSERT_EQ(in.shape(), (nn::Shape{2, cfg.input_channels(), 4, 32}));
  float range_sum = 0;
  for (int n = 0; n < 2; ++n)
    for (std::size_t i = 0; i < in.shape().plane(); ++i) range_sum += in.channel(n, 0)[i];
  EXPECT_NEAR(range_sum, (std::hypot(5.f, 1.f) + std::hypot(6.f, 1.f)) / 10, 1e-5);
  cfg.channels = {"range", "incidence"};
  const std::string msg = error_of([&] { data::encode_inputs(d, cfg, "d.h5"); });
  EXPECT_NE(msg.find("d.h5: channel 'incidence'"), std::string::npos) << msg;
}
