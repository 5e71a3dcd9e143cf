#include "fuzz/readers.h"

#include <unistd.h>

#include <filesystem>
#include <fstream>

#include "common/error.h"
#include "data/dataset.h"
#include "data/kitti_object.h"
#include "data/kitti_tracking.h"
#include "data/velodyne.h"
#include "nn/checkpoint.h"
#include "nn/unet.h"
#include "pgm/projection.h"
#include "sensor/kpi_model.h"
#include "sensor/scenario.h"

namespace lidarsim::fuzz {
namespace fs = std::filesystem;

namespace {

// The readers take paths: the input goes to a file in memory-backed /dev/shm where there is one.
fs::path scratch(const std::string& suffix) {
  static const fs::path dir = [] {
    const fs::path base = fs::is_directory("/dev/shm") ? fs::path("/dev/shm") : fs::temp_directory_path();
    const fs::path d = base / ("lidarsim-fuzz-" + std::to_string(::getpid()));
    fs::create_directories(d);
    return d;
  }();
  return dir / ("input" + suffix);
}

fs::path to_file(const std::uint8_t* data, std::size_t size, const std::string& suffix) {
  const fs::path p = scratch(suffix);
  std::ofstream out(p, std::ios::binary | std::ios::trunc);
  out.write(reinterpret_cast<const char*>(data), static_cast<std::streamsize>(size));
  return p;
}

std::string to_text(const std::uint8_t* data, std::size_t size) { return {reinterpret_cast<const char*>(data), size}; }

// Rejections with a lidarsim::Error are the expected outcome for most inputs.
template <typename F>
void expect_error_or_success(F&& f) {
  try {
    f();
  } catch (const Error&) {
  }
}

data::KittiCalib axis_calib() {
  data::KittiCalib c;
  c.R0_rect.setIdentity();
  c.Tr_velo_to_cam << 0, -1, 0, 0, 0, 0, -1, 0, 1, 0, 0, 0;
  return c;
}

// A scan and, after the first 4 bytes' worth of points, its labels: both files, then the
// projection onto a small HDL-64E grid as import does.
void velodyne(const std::uint8_t* data, std::size_t size) {
  expect_error_or_success([&] {
    const auto points = data::read_velodyne_bin(to_file(data, size, ".bin"));
    pgm::ProjectOptions options;
    options.extra_channels = {"elevation", "azimuth", "height", "incidence"};
    pgm::project(points, pgm::BeamLayout::hdl64e(64), options);
  });
  expect_error_or_success([&] { data::read_label_file(to_file(data, size, ".label"), size / 4); });
}

void kitti_object_label(const std::uint8_t* data, std::size_t size) {
  expect_error_or_success([&] { data::read_kitti_object_labels(to_file(data, size, ".txt")); });
}

void kitti_calib(const std::uint8_t* data, std::size_t size) {
  expect_error_or_success([&] {
    const data::KittiCalib calib = data::read_kitti_calib(to_file(data, size, ".txt"));
    const data::KittiBoxConverter conv(calib);
    conv.convert(1.5, 1.6, 3.9, {2, 1.6, 10}, 0.1);
  });
}

void tracking_labels(const std::uint8_t* data, std::size_t size) {
  static const data::KittiBoxConverter conv(axis_calib());
  expect_error_or_success([&] { data::read_kitti_tracking_labels(to_file(data, size, ".txt"), conv); });
}

void tracking_detections(const std::uint8_t* data, std::size_t size) {
  static const data::KittiBoxConverter conv(axis_calib());
  expect_error_or_success([&] { data::read_ab3dmot_detections(to_file(data, size, ".txt"), conv); });
}

void tracking_seqmap(const std::uint8_t* data, std::size_t size) {
  expect_error_or_success([&] { data::read_kitti_seqmap(to_file(data, size, ".seqmap")); });
}

// A scenario, and its first and last frames sampled as the simulation does.
void scenario(const std::uint8_t* data, std::size_t size) {
  expect_error_or_success([&] {
    const sensor::Scenario sc = sensor::parse_scenario(to_text(data, size), "scenario.json");
    sc.sensor.beams.layout();
    sensor::Frame frame;
    sensor::sample_frame(sc, 0.0, frame);
    sensor::sample_frame(sc, sc.frame_time(std::max(0, sc.frame_count() - 1)), frame);
  });
}

void kpi_model(const std::uint8_t* data, std::size_t size) {
  expect_error_or_success([&] {
    const sensor::KpiModel m = sensor::parse_kpi_model(to_text(data, size), "kpi.json");
    sensor::kpi_model_to_json(m);
  });
}

// A checkpoint: its metadata, then (for architectures small enough to build quickly) the
// weights into a model of that architecture, with and without the optimizer.
void checkpoint(const std::uint8_t* data, std::size_t size) {
  expect_error_or_success([&] {
    const fs::path p = to_file(data, size, ".h5");
    const nn::Checkpoint meta = nn::read_checkpoint_meta(p);
    if (meta.unet.in_channels > 16 || meta.unet.out_channels > 4 || meta.unet.base > 16 || meta.unet.depth > 4) return;
    nn::UNet model(meta.unet);
    nn::load_checkpoint(p, model, nullptr);
    nn::Optimizer optimizer(meta.optimizer.value_or(nn::OptimizerConfig{}), model.params().size());
    nn::load_checkpoint(p, model, &optimizer);
  });
}

void dataset(const std::uint8_t* data, std::size_t size) {
  expect_error_or_success([&] {
    const data::Dataset d = data::read_dataset(to_file(data, size, ".h5"));
    for (int n = 0; n < d.size(); ++n) d.frame_pgm(n);
  });
}

}  // namespace

const std::vector<Target>& targets() {
  static const std::vector<Target> all = {
      {"velodyne", velodyne},
      {"kitti_object_label", kitti_object_label},
      {"kitti_calib", kitti_calib},
      {"tracking_labels", tracking_labels},
      {"tracking_detections", tracking_detections},
      {"tracking_seqmap", tracking_seqmap},
      {"scenario", scenario},
      {"kpi_model", kpi_model},
      {"checkpoint", checkpoint},
      {"dataset", dataset},
  };
  return all;
}

Entry find_target(const std::string& name) {
  for (const Target& t : targets())
    if (t.name == name) return t.run;
  return nullptr;
}

}  // namespace lidarsim::fuzz
