// lidar-data: recorded LiDAR data -> HDF5 Polar Grid Map datasets, and the reference baselines.
//   lidar-data import --semantickitti DIR | --kitti-object DIR --out file.h5 [--columns 1024]
//   lidar-data baselines file.h5     (global / class / class x range / class x row, MAE and RMSE)
//   lidar-data info file.h5
#include <cxxopts.hpp>

#include <iostream>
#include <sstream>

#include "common/atomic_file.h"
#include "common/error.h"
#include "common/progress.h"
#include "data/baselines.h"
#include "data/import.h"

namespace {

using namespace lidarsim;

const char* kUsage =
    "usage: lidar-data <command> [options]\n"
    "commands:\n"
    "  import     read SemanticKITTI or KITTI object scans into an HDF5 dataset\n"
    "  baselines  MAE/RMSE of the lookup baselines on a dataset's reference validation split\n"
    "  info       frames, channels and beam layout of a dataset\n"
    "run 'lidar-data <command> --help' for the options of a command\n";

std::vector<std::string> split_list(const std::string& s) {
  std::vector<std::string> out;
  std::stringstream ss(s);
  for (std::string item; std::getline(ss, item, ',');)
    if (!item.empty()) out.push_back(item);
  return out;
}

pgm::RowMode parse_row_mode(const std::string& s) {
  if (s == "auto") return pgm::RowMode::Auto;
  if (s == "firing_order") return pgm::RowMode::FiringOrder;
  if (s == "nearest_elevation") return pgm::RowMode::NearestElevation;
  throw Error("--rows: expected auto, firing_order or nearest_elevation, got '" + s + "'");
}

int run_import(int argc, char** argv) {
  cxxopts::Options opts("lidar-data import",
                        "Read recorded scans as they are into an HDF5 dataset (/pgm, /target, /mask).\n"
                        "Rows: KITTI scans are cut where the azimuth wraps (firing order, 64 rows); clouds not in\n"
                        "firing order fall back to the nearest beam elevation. Classes and materials: pgm/materials.h.");
  opts.add_options()
      ("semantickitti", "SemanticKITTI folder (root with sequences/NN/, or one sequence with velodyne/ and labels/)",
       cxxopts::value<std::string>())
      ("kitti-object", "KITTI object training-style folder (velodyne/, label_2/, calib/)", cxxopts::value<std::string>())
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
  auto args = opts.parse(argc, argv);
  if (args.count("help")) {
    std::cout << opts.help() << std::endl;
    return 0;
  }
  const bool sk = args.count("semantickitti"), ko = args.count("kitti-object");
  if (sk == ko) throw Error("import: give exactly one of --semantickitti DIR or --kitti-object DIR");
  if (!args.count("out")) throw Error("import: --out FILE.h5 is required");
  data::ImportOptions o;
  o.columns = args["columns"].as<int>();
  o.first = args["first"].as<int>();
  o.max_frames = args["max-frames"].as<int>();
  o.extra_channels = split_list(args["channels"].as<std::string>());
  o.row_mode = parse_row_mode(args["rows"].as<std::string>());
  o.include_unlabelled = args.count("include-unlabelled") > 0;
  o.skip_unreadable = args.count("skip-unreadable") > 0;
  if (args.count("sequences")) o.sequences = split_list(args["sequences"].as<std::string>());
  std::vector<std::string> notes;
  o.note = [&](const std::string& n) { notes.push_back(n); };
  std::unique_ptr<ProgressBar> bar;
  const bool show = !args.count("quiet");
  o.progress = [&](int done, int total) {
    if (!bar) bar = std::make_unique<ProgressBar>("import", total, show);
    if (done < total) bar->update(done, std::to_string(done) + "/" + std::to_string(total) + " scans");
  };
  data::Dataset d = sk ? data::import_semantickitti(args["semantickitti"].as<std::string>(), o)
                       : data::import_kitti_object(args["kitti-object"].as<std::string>(), o);
  if (bar) bar->finish(std::to_string(d.size()) + " scans");
  for (const auto& n : notes) std::cerr << "note: " << n << "\n";
  const std::string out = args["out"].as<std::string>();
  remove_stale_temp_files(out);  // left by a run that was killed while writing
  data::write_dataset(out, d);
  long returns = 0;
  for (std::size_t i = 0; i < d.mask.numel(); ++i) returns += d.mask.data()[i] > 0;
  std::map<std::string, int> modes;
  for (const auto& m : d.row_modes) ++modes[m];
  std::string mode_text;
  for (const auto& [m, n] : modes) mode_text += (mode_text.empty() ? "" : ", ") + m + " " + std::to_string(n);
  std::cerr << "wrote " << out << ": " << d.size() << " frames, " << d.channels.size() << " channels x " << d.rows()
            << " x " << d.cols() << ", " << returns << " cells with a return; rows: " << mode_text << "\n";
  return 0;
}

int run_baselines(int argc, char** argv) {
  cxxopts::Options opts("lidar-data baselines",
                        "Fit the lookup baselines on the training cells of a dataset and report MAE/RMSE on the\n"
                        "validation cells (azimuth sectors 3, 7, 11, 15 of 16 in every frame).");
  opts.add_options()("dataset", "dataset (.h5)", cxxopts::value<std::string>())("h,help", "show this help");
  opts.parse_positional({"dataset"});
  opts.positional_help("DATASET.h5");
  auto args = opts.parse(argc, argv);
  if (args.count("help")) {
    std::cout << opts.help() << std::endl;
    return 0;
  }
  if (!args.count("dataset")) throw Error("baselines: give a dataset file");
  const auto d = data::read_dataset(args["dataset"].as<std::string>(), {"class", "range"});
  std::cout << data::baseline_table(data::evaluate_baselines(d));
  return 0;
}

int run_info(int argc, char** argv) {
  cxxopts::Options opts("lidar-data info", "Describe a dataset.");
  opts.add_options()("dataset", "dataset (.h5)", cxxopts::value<std::string>())("h,help", "show this help");
  opts.parse_positional({"dataset"});
  auto args = opts.parse(argc, argv);
  if (args.count("help") || !args.count("dataset")) {
    std::cout << opts.help() << std::endl;
    return args.count("help") ? 0 : 1;
  }
  const auto d = data::read_dataset(args["dataset"].as<std::string>());
  std::cout << "format: " << d.source_format << "\nframes: " << d.size() << "\ngrid: " << d.rows() << " x " << d.cols()
            << "\nchannels:";
  for (const auto& c : d.channels) std::cout << " " << c;
  std::cout << "\nbeam layout: " << d.layout.name << "\nsources: " << d.sources.size() << " files\n";
  for (int n = 0; n < d.size(); ++n) std::cout << "  " << d.frames[n] << " (rows: " << d.row_modes[n] << ")\n";
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
