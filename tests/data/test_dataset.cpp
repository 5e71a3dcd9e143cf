#include <gtest/gtest.h>
#include <hdf5.h>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <iterator>
#include <string>

#include "common/error.h"
#include "data/dataset.h"
#include "data/dataset_reader.h"
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
  data::write_dataset(dir / "d.h5", two_frames());
  {  // the attribute says 5 rows, /pgm has 4
    hid_t f = H5Fopen((dir / "d.h5").c_str(), H5F_ACC_RDWR, H5P_DEFAULT);
    ASSERT_GE(f, 0);
    ASSERT_GE(H5Adelete_by_name(f, "/", "beam_layout", H5P_DEFAULT), 0);
    hid_t type = H5Tcopy(H5T_C_S1);
    H5Tset_size(type, H5T_VARIABLE);
    hid_t space = H5Screate(H5S_SCALAR);
    hid_t attr = H5Acreate_by_name(f, "/", "beam_layout", type, space, H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT);
    const std::string json = pgm::BeamLayout::uniform(5, 2, -2, 32).to_json();
    const char* p = json.c_str();
    ASSERT_GE(H5Awrite(attr, type, &p), 0);
    H5Aclose(attr);
    H5Sclose(space);
    H5Tclose(type);
    H5Fclose(f);
  }
  const std::string msg = error_of([&] { data::read_dataset(dir / "d.h5"); });
  EXPECT_NE(msg.find("dataset /pgm: shape"), std::string::npos) << msg;
}

// The in-memory overload (the fuzz target's way in) runs the same checks as the path one.
TEST(Dataset, AFileImageInMemoryReadsAsTheFileDoesAndIsRejectedAsTheFileIsWhenCut) {
  TempDir dir;
  data::write_dataset(dir / "d.h5", two_frames());
  std::ifstream in(dir / "d.h5", std::ios::binary);
  const std::string bytes{std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
  const auto f = data::read_dataset(dir / "d.h5");
  const auto m = data::read_dataset(nn::MemoryImage{bytes.data(), bytes.size(), "in-memory.h5"});
  EXPECT_EQ(m.channels, f.channels);
  EXPECT_EQ(m.frames, f.frames);
  EXPECT_EQ(m.layout.to_json(), f.layout.to_json());
  ASSERT_EQ(m.pgm.shape(), f.pgm.shape());
  EXPECT_TRUE(std::equal(m.pgm.begin(), m.pgm.end(), f.pgm.begin()));
  EXPECT_TRUE(std::equal(m.target.begin(), m.target.end(), f.target.begin()));
  EXPECT_EQ(m.point_index, f.point_index);
  for (std::size_t keep : {std::size_t{0}, std::size_t{7}, bytes.size() / 2, bytes.size() - 1}) {
    const std::string msg = error_of([&] { data::read_dataset(nn::MemoryImage{bytes.data(), keep, "cut-in-memory.h5"}); });
    EXPECT_NE(msg.find("cut-in-memory.h5"), std::string::npos) << "kept " << keep << ": " << msg;
  }
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

TEST(Dataset, PlacesRoundTripAndOldFilesFallBackToTheFrameId) {
  TempDir dir;
  auto d = two_frames();
  d.places = {{"semantickitti", "08", "000001"}, {"semantickitti", "00", "000002"}};
  data::write_dataset(dir / "d.h5", d);
  const auto r = data::read_dataset(dir / "d.h5");
  EXPECT_EQ(r.frame_place(0), (data::FramePlace{"semantickitti", "08", "000001"}));
  EXPECT_EQ(r.frame_place(1), (data::FramePlace{"semantickitti", "00", "000002"}));
  // A version 1 file: no place datasets, row modes only in the attribute.
  data::Dataset old = two_frames();
  old.frames = {"semantickitti/03/000007", "kitti_object/000123"};
  old.places.clear();
  data::write_dataset(dir / "old.h5", old);
  hid_t f = H5Fopen((dir / "old.h5").c_str(), H5F_ACC_RDWR, H5P_DEFAULT);
  ASSERT_GE(f, 0);
  for (const char* name : {"/place_source", "/place_sequence", "/place_frame", "/row_modes"})
    ASSERT_GE(H5Ldelete(f, name, H5P_DEFAULT), 0);
  H5Fclose(f);
  const auto o = data::read_dataset(dir / "old.h5");
  EXPECT_EQ(o.row_modes, old.row_modes);
  EXPECT_EQ(o.frame_place(0), (data::FramePlace{"semantickitti", "03", "000007"}));
  EXPECT_EQ(o.frame_place(1), (data::FramePlace{"kitti_object", "", "000123"}));
}

TEST(Dataset, FrameArraysAreChunkedOneFramePerChunkShuffledDeflatedAndChecksummed) {
  TempDir dir;
  data::write_dataset(dir / "d.h5", two_frames());
  hid_t f = H5Fopen((dir / "d.h5").c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  ASSERT_GE(f, 0);
  for (const char* name : {"/pgm", "/target", "/mask", "/point_index"}) {
    hid_t ds = H5Dopen2(f, name, H5P_DEFAULT);
    ASSERT_GE(ds, 0) << name;
    hid_t plist = H5Dget_create_plist(ds);
    hsize_t chunk[4] = {0, 0, 0, 0};
    ASSERT_EQ(H5Pget_layout(plist), H5D_CHUNKED) << name;
    H5Pget_chunk(plist, 4, chunk);
    EXPECT_EQ(chunk[0], 1u) << name;
    std::vector<H5Z_filter_t> filters;
    for (int i = 0; i < H5Pget_nfilters(plist); ++i) {
      unsigned flags = 0;
      size_t nelems = 0;
      filters.push_back(H5Pget_filter2(plist, i, &flags, &nelems, nullptr, 0, nullptr, nullptr));
    }
    EXPECT_NE(std::find(filters.begin(), filters.end(), H5Z_FILTER_SHUFFLE), filters.end()) << name;
    EXPECT_NE(std::find(filters.begin(), filters.end(), H5Z_FILTER_DEFLATE), filters.end()) << name;
    // Fletcher-32 last: it sums each chunk as stored, after compression.
    ASSERT_FALSE(filters.empty()) << name;
    EXPECT_EQ(filters.back(), H5Z_FILTER_FLETCHER32) << name;
    H5Pclose(plist);
    H5Dclose(ds);
  }
  H5Fclose(f);
}

namespace {
// Writes a variable-length string attribute or 1-D dataset, as files written by older builds hold them.
void write_vlen_attr(hid_t obj, const char* name, const std::string& value) {
  hid_t type = H5Tcopy(H5T_C_S1);
  H5Tset_size(type, H5T_VARIABLE);
  hid_t space = H5Screate(H5S_SCALAR);
  hid_t a = H5Acreate2(obj, name, type, space, H5P_DEFAULT, H5P_DEFAULT);
  const char* p = value.c_str();
  H5Awrite(a, type, &p);
  H5Aclose(a), H5Sclose(space), H5Tclose(type);
}
void write_vlen_strings(hid_t file, const char* name, const std::vector<std::string>& values) {
  hid_t type = H5Tcopy(H5T_C_S1);
  H5Tset_size(type, H5T_VARIABLE);
  hsize_t n = values.size();
  hid_t space = H5Screate_simple(1, &n, nullptr);
  hid_t ds = H5Dcreate2(file, name, type, space, H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT);
  std::vector<const char*> ptrs;
  for (const auto& v : values) ptrs.push_back(v.c_str());
  H5Dwrite(ds, type, H5S_ALL, H5S_ALL, H5P_DEFAULT, ptrs.data());
  H5Dclose(ds), H5Sclose(space), H5Tclose(type);
}
void write_plain(hid_t file, const char* name, hid_t type, std::vector<hsize_t> dims, const void* data) {
  hid_t space = H5Screate_simple(static_cast<int>(dims.size()), dims.data(), nullptr);
  hid_t ds = H5Dcreate2(file, name, type, space, H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT);
  H5Dwrite(ds, type, H5S_ALL, H5S_ALL, H5P_DEFAULT, data);
  H5Dclose(ds), H5Sclose(space);
}
}  // namespace

TEST(Dataset, OldFilesWithVariableLengthStringsAndNoChecksumsStillLoad) {
  TempDir dir;
  const auto d = two_frames();
  const hsize_t n = d.size(), c = d.channels.size(), h = d.rows(), w = d.cols();
  hid_t f = H5Fcreate((dir / "old.h5").c_str(), H5F_ACC_TRUNC, H5P_DEFAULT, H5P_DEFAULT);  // default (1.8-compatible) format
  ASSERT_GE(f, 0);
  write_plain(f, "/pgm", H5T_NATIVE_FLOAT, {n, c, h, w}, d.pgm.data());
  write_plain(f, "/target", H5T_NATIVE_FLOAT, {n, 1, h, w}, d.target.data());
  std::vector<std::uint8_t> mask(d.mask.begin(), d.mask.end());
  write_plain(f, "/mask", H5T_NATIVE_UINT8, {n, 1, h, w}, mask.data());
  write_vlen_strings(f, "/frames", d.frames);
  write_vlen_strings(f, "/sources", d.sources);
  hid_t root = H5Gopen2(f, "/", H5P_DEFAULT);
  write_vlen_attr(root, "format", "lidarsim-dataset");
  write_vlen_attr(root, "channels", R"(["range","class","material"])");
  write_vlen_attr(root, "beam_layout", d.layout.to_json());
  write_vlen_attr(root, "source_format", "test");
  write_vlen_attr(root, "row_modes", R"(["nearest_elevation","nearest_elevation"])");
  H5Gclose(root);
  H5Fclose(f);
  const auto r = data::read_dataset(dir / "old.h5");
  EXPECT_EQ(r.frames, d.frames);
  EXPECT_EQ(r.sources, d.sources);
  EXPECT_EQ(r.source_format, "test");
  EXPECT_EQ(r.row_modes.size(), 2u);
  EXPECT_TRUE(std::equal(r.pgm.begin(), r.pgm.end(), d.pgm.begin(), d.pgm.end()));
  EXPECT_TRUE(std::equal(r.target.begin(), r.target.end(), d.target.begin(), d.target.end()));
}
