// lidar-infer predict on the bundled scan with the bundled model, and the point-cloud writers.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>

#include <nlohmann/json.hpp>

#include "common/error.h"
#include "common/plot.h"
#include "data/point_cloud_io.h"
#include "infer/scan_prediction.h"
#include "pgm/polar_grid_map.h"
#include "tests/support/file_bytes.h"
#include "tests/support/image_checks.h"
#include "tests/support/shared_data.h"
#include "tests/support/temp_path.h"

using lidarsim::testing::read_bytes;

namespace fs = std::filesystem;
using namespace lidarsim;

namespace {

// Runs lidar-infer with `args`; returns the exit code and leaves stderr in `err`.
int run_infer(const std::string& args, std::string& err) {
  const fs::path exe = lidarsim::testing::binary_dir() / "infer" / "lidar-infer";
  const fs::path err_file = lidarsim::testing::temp_path("predict_err.txt");
  const int rc = std::system((exe.string() + " " + args + " >/dev/null 2>" + err_file.string()).c_str());
  err = read_bytes(err_file);
  return WEXITSTATUS(rc);
}

}  // namespace

TEST(PredictCli, BundledModelOnTheBundledScanWritesCloudImageAndSummary) {
  const fs::path out = lidarsim::testing::temp_path("predict");
  fs::remove_all(out);
  const fs::path model = lidarsim::testing::source_dir() / "data/models/intensity_unet.h5";
  const fs::path scans = lidarsim::testing::source_dir() / "data/samples/semantickitti";
  std::string err;
  ASSERT_EQ(run_infer("predict --quiet --model " + model.string() + " --semantickitti " + scans.string() +
                          " --out " + out.string(),
                      err),
            0)
      << err;
  const std::string cloud = read_bytes(out / "00_000000.pcd");
  EXPECT_NE(cloud.find("FIELDS x y z intensity predicted_intensity abs_error class"), std::string::npos);
  EXPECT_NE(cloud.find("POINTS 124668"), std::string::npos);  // every point of the scan
  EXPECT_TRUE(fs::exists(out / "00_000000_intensity.png"));
  const auto summary = nlohmann::json::parse(read_bytes(out / "summary.json"));
  // All cells of the scan, training sectors included: far better than the global mean (~0.11).
  EXPECT_LT(summary.at("mae").get<double>(), 0.08);
  EXPECT_GT(summary.at("cells").get<long>(), 50000);
  EXPECT_FALSE(summary.at("per_class").empty());
}

using test::count_colour;

// The picture explains itself: a header naming the scan, a caption and colour scale above each
// row, the rows as they were.
TEST(PredictPicture, RowsHaveCaptionsAndColourScalesBelowAHeaderNamingTheScan) {
  pgm::PolarGridMap grid(pgm::BeamLayout::uniform(8, 2, -24, 1024), {"intensity", "mask"});
  for (int col = 0; col < 1024; ++col) {
    grid.at(grid.channel_index("mask"), 4, col) = 1;
    grid.at(grid.channel_index("intensity"), 4, col) = 0.25f;
  }
  const std::vector<float> predicted(grid.cells(), 0.75f);
  const Image im = infer::comparison_image(grid, predicted, "scan 00_000000");
  const int band = band_height(2), row = 192, gap = 4;  // 8 beams, 24 px each
  ASSERT_EQ(im.width, 1024);
  ASSERT_EQ(im.height, band + 3 * (band + row) + 2 * gap);
  EXPECT_GT(count_colour(im, 0, 0, 1024, band, {0, 0, 0}), 200) << "header";
  const TextStyle style;
  for (int k = 0; k < 3; ++k) {
    const int top = band + k * (band + row + gap);
    EXPECT_GT(count_colour(im, 0, top, 400, top + band, style.ink), 100) << "caption of row " << k;
    EXPECT_GT(count_colour(im, 600, top, 1024, top + band, colormap_viridis(0)), 5) << "colour scale of row " << k;
    EXPECT_GT(count_colour(im, 600, top, 1024, top + band, style.ink), 20) << "scale's end values, row " << k;
  }
  // The data: beam 4 measured 0.25 and off by 0.5, the top of the error scale.
  const int measured = 2 * band + 4 * 24, error = measured + 2 * (row + gap + band);
  EXPECT_EQ(count_colour(im, 0, measured, 1024, measured + 24, colormap_viridis(0.25f)), 1024 * 24);
  EXPECT_EQ(count_colour(im, 0, error, 1024, error + 24, colormap_viridis(1)), 1024 * 24);
}

TEST(PredictCli, MissingModelGivesOneLineNamingTheFileAndNonZeroExit) {
  std::string err;
  const int rc = run_infer("predict --quiet --model /nonexistent/model.h5 --scan /nonexistent/scan.bin --out " +
                               lidarsim::testing::temp_path("predict_bad").string(),
                           err);
  EXPECT_NE(rc, 0);
  EXPECT_NE(err.find("/nonexistent/model.h5"), std::string::npos) << err;
  EXPECT_EQ(std::count(err.begin(), err.end(), '\n'), 1) << err;
}

TEST(PredictCli, ATruncatedScanNamesTheFile) {
  const fs::path dir = lidarsim::testing::temp_path("predict_trunc");
  fs::create_directories(dir);
  const fs::path scan = dir / "000000.bin";
  std::ofstream(scan, std::ios::binary) << std::string(16 * 10 + 7, '\0');  // not a multiple of 16 bytes
  std::string err;
  const fs::path model = lidarsim::testing::source_dir() / "data/models/intensity_unet.h5";
  const int rc = run_infer("predict --quiet --model " + model.string() + " --scan " + scan.string() + " --out " +
                               (dir / "out").string(),
                           err);
  EXPECT_NE(rc, 0);
  EXPECT_NE(err.find("000000.bin"), std::string::npos) << err;
}

TEST(PointCloudIo, PcdAndPlyHeadersDescribeTheFieldsAndTheBinaryBodyHasEveryValue) {
  data::PointCloud cloud;
  cloud.add_field("x", {1.f, 2.f});
  cloud.add_field("y", {3.f, 4.f});
  cloud.add_field("z", {5.f, 6.f});
  cloud.add_field("intensity", {0.25f, 0.5f});
  const fs::path dir = lidarsim::testing::temp_path("cloud_io");
  fs::create_directories(dir);
  data::write_point_cloud(dir / "a.pcd", cloud);
  data::write_point_cloud(dir / "a.ply", cloud);
  const std::string pcd = read_bytes(dir / "a.pcd"), ply = read_bytes(dir / "a.ply");
  const std::string pcd_header_end = "DATA binary\n";
  ASSERT_NE(pcd.find(pcd_header_end), std::string::npos);
  EXPECT_NE(pcd.find("SIZE 4 4 4 4\nTYPE F F F F\nCOUNT 1 1 1 1\nWIDTH 2\n"), std::string::npos);
  EXPECT_EQ(pcd.size() - (pcd.find(pcd_header_end) + pcd_header_end.size()), 2u * 4u * sizeof(float));
  float second_intensity = 0;
  std::memcpy(&second_intensity, pcd.data() + pcd.size() - sizeof(float), sizeof(float));
  EXPECT_EQ(second_intensity, 0.5f);
  EXPECT_NE(ply.find("element vertex 2\nproperty float x\n"), std::string::npos);
  EXPECT_EQ(ply.size() - (ply.find("end_header\n") + 11), 2u * 4u * sizeof(float));
  EXPECT_THROW(data::write_point_cloud(dir / "a.xyz", cloud), Error);
  EXPECT_THROW(cloud.add_field("bad", {1.f}), Error);
}
