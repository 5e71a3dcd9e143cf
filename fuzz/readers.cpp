#include "fuzz/readers.h"

#include <hdf5.h>
#include <unistd.h>

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "common/error.h"
#include "data/class_table.h"
#include "data/dataset.h"
#include "data/dataset_reader.h"
#include "data/kitti_object.h"
#include "data/kitti_tracking.h"
#include "data/nuscenes.h"
#include "data/ouster.h"
#include "data/ply_reader.h"
#include "data/rellis3d.h"
#include "data/velodyne.h"
#include "nn/checkpoint.h"
#include "nn/checkpoint_image.h"
#include "nn/unet.h"
#include "osi/osi3_subset.pb.h"
#include "osi/sensor_data.h"
#include "osi/sensor_view.h"
#include "osi/sensor_view_decoder.h"
#include "osi/trace.h"
#include "pgm/projection.h"
#include "sensor/kpi_model.h"
#include "sensor/scenario.h"
#include "tests/osi/sensor_view_oracle.h"

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

// HDF5 inputs are opened as file images in memory (the readers' MemoryImage overloads: the same
// checks as on a path, with HDF5's core driver instead of a file per input). HDF5 callocs its
// metadata cache (over 0.5 MB) on every open and, past its free lists' default limits, returns it
// to malloc on close: under ASan that is a fresh mapping per input, and page faults and memset
// were 90% of the time (14 inputs/s). Unlimited free lists let HDF5 reuse its own blocks; what
// our code allocates is still checked by ASan and LeakSanitizer.
nn::MemoryImage image(const std::uint8_t* data, std::size_t size, const char* name) {
  static const bool reuse = H5set_free_list_limits(-1, -1, -1, -1, -1, -1) >= 0;
  (void)reuse;
  return {data, size, name};
}

// A checkpoint: its metadata, then (for architectures small enough to build quickly) the
// weights into a model of that architecture, with and without the optimizer.
void checkpoint(const std::uint8_t* data, std::size_t size) {
  expect_error_or_success([&] {
    const nn::MemoryImage file = image(data, size, "checkpoint.h5");
    const nn::Checkpoint meta = nn::read_checkpoint_meta(file);
    if (meta.unet.in_channels > 16 || meta.unet.out_channels > 4 || meta.unet.base > 16 || meta.unet.depth > 4) return;
    nn::UNet model(meta.unet);
    nn::load_checkpoint(file, model, nullptr);
    nn::Optimizer optimizer(meta.optimizer.value_or(nn::OptimizerConfig{}), model.params().size());
    nn::load_checkpoint(file, model, &optimizer);
  });
}

void dataset(const std::uint8_t* data, std::size_t size) {
  expect_error_or_success([&] {
    const data::Dataset d = data::read_dataset(image(data, size, "dataset.h5"));
    for (int n = 0; n < d.size(); ++n) d.frame_pgm(n);
  });
}


// Ouster metadata JSON: parsed, then the layout and packet size the pcap reader derives from it.
void ouster_metadata(const std::uint8_t* data, std::size_t size) {
  expect_error_or_success([&] {
    const data::OusterMetadata m = data::read_ouster_metadata(to_file(data, size, ".json"));
    m.layout();
    m.packet_bytes();
  });
}

// An Ouster metadata of each parsed packet profile, all 32 beams x 512 columns (an OS-1-32 in
// 512x10 mode): the parser's logic does not depend on the size, but each frame costs rows x
// columns cells, and at 128 x 1024 (1.3 MB, allocated afresh under ASan) that was most of an
// input's time. scripts/fuzz.sh rewrites the sample captures to this size (fuzz/ouster_seed.py).
std::vector<data::OusterMetadata> ouster_profiles() {
  std::vector<data::OusterMetadata> all;
  for (const char* profile : {"LEGACY", "RNG15_RFL8_NIR8", "RNG19_RFL8_SIG16_NIR16"}) {
    const int rows = 32;
    data::OusterMetadata m;
    m.path = std::string("fuzz-") + profile + ".json";
    m.udp_profile_lidar = profile;
    m.columns_per_frame = 512;
    m.columns_per_packet = 16;
    m.pixels_per_column = rows;
    m.lidar_origin_to_beam_origin_mm = 15.8;
    for (int r = 0; r < rows; ++r) {
      m.beam_altitude_deg.push_back(22.5 - 45.0 * r / (rows - 1));
      m.beam_azimuth_deg.push_back(r % 4 == 0 ? 4.2 : -1.3);
    }
    all.push_back(m);
  }
  return all;
}

// A pcap, read with the metadata of every profile, and each frame's points.
void ouster_pcap(const std::uint8_t* data, std::size_t size) {
  static const std::vector<data::OusterMetadata> profiles = ouster_profiles();
  const fs::path p = to_file(data, size, ".pcap");
  for (const auto& meta : profiles)
    expect_error_or_success([&] {
      for (const auto& frame : data::read_ouster_pcap(p, meta)) data::ouster_points(frame, meta);
    });
}

// A nuScenes .pcd.bin sweep, then the projection onto a 32-beam grid as import does.
void nuscenes(const std::uint8_t* data, std::size_t size) {
  expect_error_or_success([&] {
    const auto points = data::read_nuscenes_pcd_bin(to_file(data, size, ".pcd.bin"));
    pgm::ProjectOptions options;
    options.extra_channels = {"elevation", "incidence"};
    pgm::project(points, pgm::BeamLayout::uniform(32, 10.67, -30.67, 64), options);
  });
}

// A RELLIS-3D scan: the input's first 16/20 are the organized .bin (16 bytes a point), the
// rest its .label (4 bytes a point), mapped through the bundled RELLIS class table.
void rellis3d(const std::uint8_t* data, std::size_t size) {
  static const data::ClassTable table =
      data::read_class_table(fs::path(LIDARSIM_SOURCE_DIR) / "data/ontologies/rellis3d.csv");
  const std::size_t bin = size / 20 * 16;
  data::Rellis3dFiles files;
  files.bin = to_file(data, bin, ".bin");
  files.label = to_file(data + bin, size - bin, ".label");
  expect_error_or_success([&] { data::read_rellis3d_scan(files, table); });
}

// A PLY cloud (RELLIS-3D's reflectivity comes from one), binary or ASCII.
void ply(const std::uint8_t* data, std::size_t size) {
  expect_error_or_success([&] { data::read_ply(to_file(data, size, ".ply")); });
}

// A class table CSV (data/ontologies/), and a lookup of every id in it.
void class_table(const std::uint8_t* data, std::size_t size) {
  expect_error_or_success([&] {
    const data::ClassTable t = data::read_class_table(to_file(data, size, ".csv"));
    for (const auto& [id, e] : t.entries) t.map(id), t.name_of(id);
    t.name_of(-1);
  });
}

// A sensor's beam layout JSON (data/sensors/*.json, scenarios, checkpoints), then a few
// directions binned on it.
void sensor_layout(const std::uint8_t* data, std::size_t size) {
  expect_error_or_success([&] {
    const pgm::BeamLayout l = pgm::BeamLayout::from_file(to_file(data, size, ".json").string());
    l.validate();
    for (double e : {0.5, 0.0, -0.5}) l.nearest_row(e);
    l.column_of(1.0, -0.3);
    l.azimuth_of_column(l.columns - 1);
    pgm::BeamLayout::from_json(l.to_json());
  });
}

// A binary OSI trace as `lidar-infer osi` reads it: each message decoded by hand (osi/sensor_view_decoder.h)
// and turned into the scene (at most 16 messages per input), and the scene's SensorData (no
// objects, empty clouds) encoded by hand and by libprotobuf. libprotobuf is the oracle twice: it
// must parse exactly the messages the decoder accepts, into the same fields
// (tests/osi/sensor_view_oracle.h), and what the input echoes (timestamp, ids, mounts, with
// whatever unknown fields they carry) must give the same bytes both ways.
void osi_trace(const std::uint8_t* data, std::size_t size) {
  expect_error_or_success([&] {
    std::istringstream in(to_text(data, size));
    osi::TraceReader reader(in, "trace.osi");
    std::string view_bytes;
    osi::msg::SensorView view;
    osi::IdMap ids;
    osi::SceneFrame frame;
    osi3::SensorData message;
    std::string bytes;
    for (int n = 0; n < 16 && reader.next(view_bytes); ++n) {
      if (const std::string diff = osi::oracle::compare_with_libprotobuf(view_bytes); !diff.empty()) {
        std::fprintf(stderr, "osi_trace: message %d: the decoder and libprotobuf differ: %s\n", n, diff.c_str());
        std::abort();
      }
      osi::decode_sensor_view(view_bytes, "trace.osi", reader.index(), view);
      osi::scene_from_sensor_view(view, reader.index(), "trace.osi", ids, frame);
      const std::vector<osi::CloudRef> clouds(frame.detectors.size());
      osi::build_sensor_data(frame, {}, {}, clouds, ids, static_cast<std::uint64_t>(n), message);
      osi::encode_sensor_data(frame, {}, {}, clouds, ids, static_cast<std::uint64_t>(n), bytes);
      if (bytes != message.SerializeAsString()) {
        std::fprintf(stderr, "osi_trace: message %d: the encoder's SensorData differs from libprotobuf's\n", n);
        std::abort();
      }
    }
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
      {"ouster_metadata", ouster_metadata},
      {"ouster_pcap", ouster_pcap},
      {"nuscenes", nuscenes},
      {"rellis3d", rellis3d},
      {"ply", ply},
      {"class_table", class_table},
      {"sensor_layout", sensor_layout},
      {"osi_trace", osi_trace},
  };
  return all;
}

Entry find_target(const std::string& name) {
  for (const Target& t : targets())
    if (t.name == name) return t.run;
  return nullptr;
}

}  // namespace lidarsim::fuzz
