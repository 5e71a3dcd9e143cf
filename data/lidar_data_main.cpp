// lidar-data: recorded LiDAR data -> HDF5 Polar Grid Map datasets, and the reference baselines.
//   lidar-data import --semantickitti DIR | --kitti-object DIR | --nuscenes DIR | --rellis3d DIR
//                     | --ouster PCAP | --nuscenes-lidarseg DIR | --semantickitti-mos DIR
//                     --out file.h5 [--columns 1024] [--sensor layout.json]
//   lidar-data baselines file.h5     (global / class / class x range / class x row, MAE and RMSE)
//   lidar-data info file.h5 [--png frame.png]
//   lidar-data layout --ouster-metadata X.json --out layout.json
#include <cxxopts.hpp>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <iostream>
#include <map>
#include <nlohmann/json.hpp>
#include <sstream>

#include "common/atomic_file.h"
#include "common/error.h"
#include "common/image.h"
#include "common/plot.h"
#include "common/progress.h"
#include "data/baselines.h"
#include "data/dataset_reader.h"
#include "data/split.h"
#include "nn/receptive_field.h"
#include "data/import.h"
#include "data/ouster.h"

namespace {

using namespace lidarsim;

const char* kUsage =
    "usage: lidar-data <command> [options]\n"
    "commands:\n"
    "  import     read SemanticKITTI (or its moving-object labels), KITTI object, nuScenes(-lidarseg), RELLIS-3D or\n"
    "             Ouster scans into an HDF5 dataset\n"
    "  layout     write the beam layout JSON of an Ouster sensor from its metadata\n"
    "  baselines  MAE/RMSE of the lookup baselines on a dataset's validation split (default: guarded)\n"
    "  info       frames, channels and beam layout of a dataset\n"
    "run 'lidar-data <command> --help' for the options of a command\n";

std::vector<std::string> split_list(const std::string& s) {
  std::vector<std::string> out;
  std::stringstream ss(s);
  for (std::string item; std::getline(ss, item, ',');)
    if (!item.empty()) out.push_back(item);
  return out;
}

// A bundled file (relative path): the current directory first, then the source tree.
std::string resolve_default(const std::string& relative) {
  if (std::filesystem::exists(relative)) return relative;
  const std::filesystem::path in_source = std::filesystem::path(LIDARSIM_SOURCE_DIR) / relative;
  return std::filesystem::exists(in_source) ? in_source.string() : relative;
}

pgm::RowMode parse_row_mode(const std::string& s) {
  if (s == "auto") return pgm::RowMode::Auto;
  if (s == "firing_order") return pgm::RowMode::FiringOrder;
  if (s == "nearest_elevation") return pgm::RowMode::NearestElevation;
  throw Error("--rows: expected auto, firing_order or nearest_elevation, got '" + s + "'");
}

std::string counts_text(const std::map<std::string, long long>& counts) {
  std::vector<std::pair<long long, std::string>> order;
  for (const auto& [name, n] : counts) order.emplace_back(-n, name);
  std::sort(order.begin(), order.end());  // largest first
  std::string text;
  for (const auto& [n, name] : order) text += (text.empty() ? "" : ", ") + name + " " + std::to_string(-n);
  return text.empty() ? "none" : text;
}

// What was read, dropped and imported, in points of the scan files (the grid keeps one per cell).
void print_point_counts(const data::ImportSummary& s) {
  std::cerr << "points: " << s.points << " read";
  if (s.dropped_points) std::cerr << ", " << s.dropped_points << " dropped by the reader (nuScenes-lidarseg: vehicle.ego)";
  std::cerr << ", " << s.points - s.dropped_points << " imported\nclasses (points): " << counts_text(s.classes) << "\n";
  if (!s.unmapped.empty()) std::cerr << "imported as unlabeled (no class of ours): " << counts_text(s.unmapped) << "\n";
  if (!s.motion.empty()) std::cerr << "motion (points): " << counts_text(s.motion) << "\n";
  std::cerr << "intensity scale: " << s.intensity_scale.describe() << "\n";
}

cxxopts::Options import_options() {
  cxxopts::Options opts("lidar-data import",
                        "Read recorded scans as they are into an HDF5 dataset (/pgm, /target, /mask).\n"
                        "Rows: KITTI scans are cut where the azimuth wraps (firing order, 64 rows); clouds not in\n"
                        "firing order fall back to the nearest beam elevation. Classes and materials: pgm/materials.h.");
  opts.add_options()
      ("semantickitti", "SemanticKITTI folder (root with sequences/NN/, or one sequence with velodyne/ and labels/)",
       cxxopts::value<std::string>())
      ("kitti-object", "KITTI object training-style folder (velodyne/, label_2/, calib/)", cxxopts::value<std::string>())
      ("nuscenes", "folder of nuScenes LIDAR_TOP .pcd.bin sweeps (HDL-32E)", cxxopts::value<std::string>())
      ("rellis3d", "RELLIS-3D OS1-64 scans (.bin + .label, PLY for reflectivity)", cxxopts::value<std::string>())
      ("ouster", "Ouster .pcap (or a folder of them) with the sensor's JSON metadata", cxxopts::value<std::string>())
      ("nuscenes-lidarseg", "nuScenes-lidarseg folder: velodyne/*.pcd.bin with labels/*.lidarseg.bin (HDL-32E); "
       "classes through --classes, the ego car's points (class 31) dropped", cxxopts::value<std::string>())
      ("semantickitti-mos", "SemanticKITTI scans whose labels are moving/static only (labels_mos/*.label: 8 static, "
       "250 movable, 251 moving): class unlabeled, a 'motion' channel 0 static, 1 movable, 2 moving",
       cxxopts::value<std::string>())
      ("sensor", "beam layout JSON to project onto (default: the format's sensor, data/sensors/)", cxxopts::value<std::string>())
      ("classes", "class table of --rellis3d / --nuscenes-lidarseg (default: data/ontologies/rellis3d.csv / nuscenes-lidarseg.csv)",
       cxxopts::value<std::string>())
      ("metadata", "Ouster JSON metadata (default: beside the pcap)", cxxopts::value<std::string>())
      ("out", "output dataset (.h5), written atomically", cxxopts::value<std::string>())
      ("columns", "azimuth bins (multiple of 16; 1024 or 2048)", cxxopts::value<int>()->default_value("1024"))
      ("sequences", "SemanticKITTI sequences to read, comma-separated (default all)", cxxopts::value<std::string>())
      ("first", "skip this many frames", cxxopts::value<int>()->default_value("0"))
      ("max-frames", "read at most this many frames (0 = all)", cxxopts::value<int>()->default_value("0"))
      ("channels", "extra /pgm channels besides range, class, material",
       cxxopts::value<std::string>()->default_value("elevation,azimuth,height,incidence"))
      ("rows", "row assignment: auto, firing_order, nearest_elevation", cxxopts::value<std::string>()->default_value("auto"))
      ("include-unlabelled", "also import SemanticKITTI scans without labels (class 0)")
      ("skip-unreadable", "skip listed scans that cannot be read (counted and named) instead of stopping")
      ("quiet", "no progress bar")
      ("h,help", "show this help");
  return opts;
}

// The one source given: the flag names the format.
std::pair<data::SourceFormat, std::string> import_source(const cxxopts::ParseResult& args) {
  std::vector<std::pair<data::SourceFormat, std::string>> given;
  for (const auto& [flag, format] : std::vector<std::pair<std::string, data::SourceFormat>>{
           {"semantickitti", data::SourceFormat::SemanticKitti}, {"kitti-object", data::SourceFormat::KittiObject},
           {"nuscenes", data::SourceFormat::Nuscenes}, {"rellis3d", data::SourceFormat::Rellis3d},
           {"ouster", data::SourceFormat::Ouster}, {"nuscenes-lidarseg", data::SourceFormat::NuscenesLidarseg},
           {"semantickitti-mos", data::SourceFormat::SemanticKittiMos}})
    if (args.count(flag)) given.emplace_back(format, args[flag].as<std::string>());
  if (given.size() != 1)
    throw Error("import: give exactly one of --semantickitti, --kitti-object, --nuscenes, --rellis3d, --nuscenes-lidarseg, "
                "--semantickitti-mos DIR or --ouster PCAP");
  return given[0];
}

// The import settings of the command line, with the format's default sensor and class table.
data::ImportOptions import_settings(const cxxopts::ParseResult& args, data::SourceFormat format) {
  data::ImportOptions o;
  o.columns = args["columns"].as<int>();
  o.first = args["first"].as<int>();
  o.max_frames = args["max-frames"].as<int>();
  o.extra_channels = split_list(args["channels"].as<std::string>());
  o.row_mode = parse_row_mode(args["rows"].as<std::string>());
  o.include_unlabelled = args.count("include-unlabelled") > 0;
  o.skip_unreadable = args.count("skip-unreadable") > 0;
  if (args.count("sequences")) o.sequences = split_list(args["sequences"].as<std::string>());
  // Sensors as data: the layout files under data/sensors/ (the HDL-64E of KITTI stays built in).
  std::string sensor;
  if (args.count("sensor")) sensor = args["sensor"].as<std::string>();
  else if (format == data::SourceFormat::Nuscenes || format == data::SourceFormat::NuscenesLidarseg)
    sensor = resolve_default("data/sensors/hdl32e-nuscenes.json");
  else if (format == data::SourceFormat::Rellis3d) sensor = resolve_default("data/sensors/os1-64-rellis3d.json");
  if (!sensor.empty()) o.layout = pgm::BeamLayout::from_file(sensor);
  if (args.count("classes")) o.class_table = args["classes"].as<std::string>();
  else if (format == data::SourceFormat::Rellis3d) o.class_table = resolve_default("data/ontologies/rellis3d.csv");
  else if (format == data::SourceFormat::NuscenesLidarseg) o.class_table = resolve_default("data/ontologies/nuscenes-lidarseg.csv");
  if (args.count("metadata")) o.ouster_metadata = args["metadata"].as<std::string>();
  return o;
}

void print_import_summary(const data::ImportSummary& summary, const std::vector<std::string>& notes, const std::string& out) {
  for (const auto& n : notes) std::cerr << "note: " << n << "\n";
  std::string mode_text;
  for (const auto& [m, n] : summary.row_modes) mode_text += (mode_text.empty() ? "" : ", ") + m + " " + std::to_string(n);
  std::cerr << "wrote " << out << ": " << summary.frames << " frames, " << summary.channels.size() << " channels x "
            << summary.layout.rows() << " x " << summary.layout.columns << ", " << summary.returns
            << " cells with a return; rows: " << mode_text << "\n";
  print_point_counts(summary);
}

int run_import(int argc, char** argv) {
  cxxopts::Options opts = import_options();
  auto args = opts.parse(argc, argv);
  if (args.count("help")) {
    std::cout << opts.help() << std::endl;
    return 0;
  }
  const auto [format, source] = import_source(args);
  if (!args.count("out")) throw Error("import: --out FILE.h5 is required");
  data::ImportOptions o = import_settings(args, format);
  std::vector<std::string> notes;
  o.note = [&](const std::string& n) { notes.push_back(n); };
  std::unique_ptr<ProgressBar> bar;
  const bool show = !args.count("quiet");
  o.progress = [&](int done, int total) {
    if (!bar) bar = std::make_unique<ProgressBar>("import", total, show);
    if (done < total) bar->update(done, std::to_string(done) + "/" + std::to_string(total) + " scans");
  };
  const std::string out = args["out"].as<std::string>();
  remove_stale_temp_files(out);  // left by a run that was killed while writing
  const auto summary = data::import_to_file(format, source, out, o);
  if (bar) bar->finish(std::to_string(summary.frames) + " scans");
  print_import_summary(summary, notes, out);
  return 0;
}

int run_baselines(int argc, char** argv) {
  cxxopts::Options opts("lidar-data baselines",
                        "Fit the lookup baselines on the training cells of a dataset and report MAE/RMSE on the\n"
                        "validation cells of --split (data/split.h). The default, guarded, holds out the same\n"
                        "cells as lidar-train's default for the bundled recipe (base 8, depth 3).");
  opts.add_options()("dataset", "dataset (.h5)", cxxopts::value<std::string>())(
      "split", "guarded | guarded:<receptive-field half-width> | interleaved (old, leaks) | frames:<id>,...",
      cxxopts::value<std::string>()->default_value("guarded"))(
      "depth", "guarded: the guard of a UNet this deep", cxxopts::value<int>()->default_value("3"))(
      "h,help", "show this help");
  opts.parse_positional({"dataset"});
  opts.positional_help("DATASET.h5");
  auto args = opts.parse(argc, argv);
  if (args.count("help")) {
    std::cout << opts.help() << std::endl;
    return 0;
  }
  if (!args.count("dataset")) throw Error("baselines: give a dataset file");
  const auto d = data::read_dataset(args["dataset"].as<std::string>(), {"class", "range"});
  const int half = nn::receptive_field_half_width({1, 1, 8, args["depth"].as<int>()});
  const data::SectorSplit split = data::parse_split(args["split"].as<std::string>(), half, d.cols());
  std::cout << "split: " << split.describe(d.cols()) << "\n\n";
  std::cout << data::baseline_table(data::evaluate_baselines(d, split));
  return 0;
}

// One frame as people look at it: the range row above the intensity row, each under a caption
// with its colour scale; rows stretched so that a 32-beam and a 128-beam sensor read alike.
Image frame_picture(const data::DatasetReader& in, int n) {
  const int H = in.rows(), W = in.cols(), C = in.channels();
  std::vector<float> pgm(static_cast<std::size_t>(C) * H * W), target(H * W), mask(H * W);
  in.read_frame(n, pgm.data(), target.data(), mask.data());
  std::vector<std::uint8_t> valid(H * W);
  float max_range = 0, max_intensity = 0;
  const float* range = pgm.data() + static_cast<std::size_t>(in.header().channel_index("range")) * H * W;
  for (int i = 0; i < H * W; ++i) {
    valid[i] = mask[i] > 0;
    if (valid[i]) max_range = std::max(max_range, range[i]), max_intensity = std::max(max_intensity, target[i]);
  }
  // Range on a 0-50 m scale (most returns; farther ones saturate), intensity on its own maximum.
  const float range_hi = std::min(50.f, std::max(1.f, max_range));
  const float intensity_hi = std::max(1e-3f, max_intensity);
  const int factor = std::max(1, 256 / H);
  const TextStyle style;
  char hi[32];
  std::snprintf(hi, sizeof hi, "%.0f m", range_hi);
  const Image r = add_caption_band(scale_rows(field_to_image(range, valid.data(), W, H, 0, range_hi), factor),
                                   "range, " + in.header().layout.name + ", " + std::to_string(H) + " x " +
                                       std::to_string(W),
                                   ColourKey{"0", hi}, style);
  std::snprintf(hi, sizeof hi, "%.2f", intensity_hi);
  const Image t = add_caption_band(scale_rows(field_to_image(target.data(), valid.data(), W, H, 0, intensity_hi), factor),
                                   in.header().frames[n] + " intensity", ColourKey{"0", hi}, style);
  return stack_vertically({r, t});
}

int run_info(int argc, char** argv) {
  cxxopts::Options opts("lidar-data info", "Describe a dataset.");
  opts.add_options()("dataset", "dataset (.h5)", cxxopts::value<std::string>())(
      "frames", "list every frame id")("png", "write frame --frame's range and intensity rows to this PNG",
                                       cxxopts::value<std::string>())(
      "frame", "frame for --png", cxxopts::value<int>()->default_value("0"))("h,help", "show this help");
  opts.parse_positional({"dataset"});
  auto args = opts.parse(argc, argv);
  if (args.count("help") || !args.count("dataset")) {
    std::cout << opts.help() << std::endl;
    return args.count("help") ? 0 : 1;
  }
  // Header only: the frames stay on disk, so this is instant on any size of file.
  const data::DatasetReader in(args["dataset"].as<std::string>());
  const data::Dataset& d = in.header();
  std::cout << "format: " << d.source_format << "\nframes: " << in.size() << "\ngrid: " << in.rows() << " x " << in.cols()
            << "\nchannels:";
  for (const auto& c : d.channels) std::cout << " " << c;
  std::cout << "\nintensity scale: " << d.intensity_scale.describe()
            << (d.intensity_scale.recorded() ? "" : " (written before datasets recorded it)");
  std::cout << "\nbeam layout: " << d.layout.name << " (" << d.layout.rows() << " beams x " << d.layout.columns
            << " columns)\nsources: " << d.sources.size() << " files\n";
  std::map<std::pair<std::string, std::string>, int> places;
  std::map<std::string, int> modes;
  for (int n = 0; n < in.size(); ++n) {
    const auto p = d.frame_place(n);
    ++places[{p.source, p.sequence}];
    ++modes[d.row_modes[n]];
  }
  std::cout << "places (source/sequence: frames):";
  for (const auto& [p, n] : places) std::cout << " " << p.first << "/" << (p.second.empty() ? "-" : p.second) << ": " << n;
  std::cout << "\nrow modes:";
  for (const auto& [m, n] : modes) std::cout << " " << m << ": " << n;
  std::cout << "\n";
  if (args.count("frames"))
    for (int n = 0; n < in.size(); ++n) std::cout << "  " << d.frames[n] << " (rows: " << d.row_modes[n] << ")\n";
  if (args.count("png")) {
    const int n = args["frame"].as<int>();
    write_png(args["png"].as<std::string>(), frame_picture(in, n));
    std::cout << "wrote " << args["png"].as<std::string>() << " (frame " << d.frames.at(n) << ")\n";
  }
  return 0;
}

int run_layout(int argc, char** argv) {
  cxxopts::Options opts("lidar-data layout",
                        "Write a sensor's beam layout as JSON (data/sensors/ holds the bundled ones): from an\n"
                        "Ouster metadata file (beam altitudes and azimuth offsets), or check an existing layout file.");
  opts.add_options()("ouster-metadata", "Ouster JSON metadata", cxxopts::value<std::string>())(
      "check", "read a layout JSON and print its summary", cxxopts::value<std::string>())(
      "out", "output JSON (written atomically)", cxxopts::value<std::string>())("h,help", "show this help");
  auto args = opts.parse(argc, argv);
  if (args.count("help")) {
    std::cout << opts.help() << std::endl;
    return 0;
  }
  pgm::BeamLayout layout;
  if (args.count("ouster-metadata")) layout = data::read_ouster_metadata(args["ouster-metadata"].as<std::string>()).layout();
  else if (args.count("check")) layout = pgm::BeamLayout::from_file(args["check"].as<std::string>());
  else throw Error("layout: give --ouster-metadata FILE.json or --check FILE.json");
  if (args.count("out")) write_file_atomically(args["out"].as<std::string>(), nlohmann::json::parse(layout.to_json()).dump(1) + "\n");
  std::cout << layout.name << ": " << layout.rows() << " beams (" << layout.elevations_rad.front() * 180 / M_PI << " to "
            << layout.elevations_rad.back() * 180 / M_PI << " deg) x " << layout.columns << " columns"
            << (layout.azimuth_offsets_rad.empty() ? "" : ", per-beam azimuth offsets") << "\n";
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  try {
    if (argc < 2) {
      std::cerr << kUsage;
      return 2;
    }
    const std::string cmd = argv[1];
    if (cmd == "-h" || cmd == "--help" || cmd == "help") {
      std::cout << kUsage;
      return 0;
    }
    if (cmd == "import") return run_import(argc - 1, argv + 1);
    if (cmd == "baselines") return run_baselines(argc - 1, argv + 1);
    if (cmd == "info") return run_info(argc - 1, argv + 1);
    if (cmd == "layout") return run_layout(argc - 1, argv + 1);
    std::cerr << "error: unknown command '" << cmd << "'\n" << kUsage;
    return 2;
  } catch (const cxxopts::exceptions::exception& e) {
    std::cerr << "error: " << e.what() << "\n";
    return 2;
  } catch (const std::exception& e) {
    std::cerr << "error: " << e.what() << "\n";
    return 1;
  }
}
