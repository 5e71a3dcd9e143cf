// lidar-infer: run the trained models.
//   predict  intensity for recorded scans (SemanticKITTI, KITTI object, or one .bin)
#include <cstdio>
#include <cstring>
#include <iostream>
#include <string>

#include <omp.h>

#include <cxxopts.hpp>

#include "common/error.h"
#include "infer/scan_prediction.h"

namespace {

void usage() {
  std::cout << "usage: lidar-infer <command> [options]\n"
               "commands:\n"
               "  predict   predicted intensity for recorded scans: point clouds (PCD/PLY), PNG figures, summary\n"
               "run 'lidar-infer <command> --help' for the options of a command\n";
}

int run_predict(int argc, char** argv) {
  using namespace lidarsim;
  cxxopts::Options options("lidar-infer predict",
                           "Predict per-point intensity for recorded scans with a lidar-train checkpoint.\n"
                           "Writes <out>/<scan>.pcd|.ply (x y z intensity predicted_intensity abs_error class),\n"
                           "<out>/<scan>_intensity.png (rows: measured, predicted, |error|), summary.json, summary.md.");
  // clang-format off
  options.add_options()
    ("model", "checkpoint from lidar-train", cxxopts::value<std::string>())
    ("semantickitti", "SemanticKITTI folder (root, sequences/ or one sequence)", cxxopts::value<std::string>())
    ("kitti-object", "KITTI object training-style folder", cxxopts::value<std::string>())
    ("scan", "one KITTI-style .bin scan", cxxopts::value<std::string>())
    ("label", "its SemanticKITTI .label (optional)", cxxopts::value<std::string>())
    ("out", "output folder", cxxopts::value<std::string>()->default_value("out/predict"))
    ("format", "point cloud format: pcd or ply", cxxopts::value<std::string>()->default_value("pcd"))
    ("max-frames", "at most this many scans (0 = all)", cxxopts::value<int>()->default_value("0"))
    ("threads", "OpenMP threads", cxxopts::value<int>()->default_value("2"))
    ("quiet", "no progress bar")
    ("h,help", "show this help");
  // clang-format on
  const auto args = options.parse(argc, argv);
  if (args.count("help") || !args.count("model")) {
    std::cout << options.help() << "\n";
    return args.count("help") ? 0 : 2;
  }
  infer::PredictOptions o;
  o.model = args["model"].as<std::string>();
  if (args.count("semantickitti")) o.semantickitti = args["semantickitti"].as<std::string>();
  if (args.count("kitti-object")) o.kitti_object = args["kitti-object"].as<std::string>();
  if (args.count("scan")) o.scan = args["scan"].as<std::string>();
  if (args.count("label")) o.label = args["label"].as<std::string>();
  o.out = args["out"].as<std::string>();
  o.format = args["format"].as<std::string>();
  o.max_frames = args["max-frames"].as<int>();
  o.progress = !args.count("quiet");
  omp_set_num_threads(std::max(1, args["threads"].as<int>()));
  const auto summary = infer::predict_scans(o);
  std::printf("%zu scans: MAE %.4f RMSE %.4f over %ld cells, %.3f s per scan; outputs in %s (summary.md)\n",
              summary.scans.size(), summary.mae, summary.rmse, summary.cells, summary.seconds_per_scan,
              o.out.c_str());
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 2 || !std::strcmp(argv[1], "-h") || !std::strcmp(argv[1], "--help")) {
    usage();
    return argc < 2 ? 2 : 0;
  }
  const std::string command = argv[1];
  try {
    if (command == "predict") return run_predict(argc - 1, argv + 1);
    std::fprintf(stderr, "error: unknown command '%s'\n", command.c_str());
    usage();
    return 2;
  } catch (const cxxopts::exceptions::exception& e) {
    std::fprintf(stderr, "error: %s (see lidar-infer %s --help)\n", e.what(), command.c_str());
    return 2;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "error: %s\n", e.what());
    return 1;
  }
}
