// lidar-calibrate: fit the KPI manager's error model from KITTI tracking ground truth and real
// detections in the AB3DMOT layout, write it atomically, and print measured vs re-simulated
// statistics (detection rate by range bin and occlusion, miss bursts, errors) on the same GT.
#include <cxxopts.hpp>

#include <filesystem>
#include <iostream>

#include "common/atomic_file.h"
#include "common/error.h"
#include "data/kitti_tracking.h"
#include "sensor/kpi_fit.h"
#include "sensor/kpi_model.h"

namespace fs = std::filesystem;
using namespace lidarsim;

int main(int argc, char** argv) {
  try {
    cxxopts::Options opts("lidar-calibrate",
                          "Fit the KPI error model (sensor/kpi_model.h) from KITTI tracking GT + AB3DMOT detections");
    opts.add_options()
      ("kitti-tracking", "folder with label_02/, calib/, detection/<detector>_<Class>_val/", cxxopts::value<std::string>())
      ("seqmap", "sequences to use (default: DIR/evaluate_tracking.seqmap.val; those present)", cxxopts::value<std::string>())
      ("detector", "detection folder prefix", cxxopts::value<std::string>()->default_value("pointrcnn"))
      ("out", "model file to write (JSON)", cxxopts::value<std::string>())
      ("report", "also write the comparison as Markdown here", cxxopts::value<std::string>())
      ("seed", "seed of the re-simulation", cxxopts::value<std::uint64_t>()->default_value("1"))
      ("h,help", "this help");
    const auto args = opts.parse(argc, argv);
    if (args.count("help")) {
      std::cout << opts.help() << "\n";
      return 0;
    }
    if (!args.count("kitti-tracking")) throw Error("--kitti-tracking: required (the KITTI tracking folder)");
    if (!args.count("out")) throw Error("--out: required (the model file to write)");
    const fs::path root = args["kitti-tracking"].as<std::string>();
    if (!fs::is_directory(root)) throw input_error(root.string(), "--kitti-tracking", "not a directory");
    const fs::path seqmap = args.count("seqmap") ? fs::path(args["seqmap"].as<std::string>())
                                                 : root / "evaluate_tracking.seqmap.val";
    const std::string detector = args["detector"].as<std::string>();

    std::vector<sensor::CalibrationSequence> seqs;
    std::string used, missing;
    for (const std::string& name : data::read_kitti_seqmap(seqmap)) {
      if (!fs::exists(root / "label_02" / (name + ".txt"))) {
        missing += " " + name;
        continue;
      }
      seqs.push_back(data::to_calibration_sequence(data::read_kitti_tracking_sequence(root, name, detector)));
      used += " " + name;
    }
    if (seqs.empty()) throw input_error(seqmap.string(), "sequences", "none of the listed sequences is present");
    std::cerr << "sequences used:" << used << (missing.empty() ? "" : "; listed but absent:" + missing) << "\n";

    const sensor::FitOptions fit;
    sensor::KpiModel model = sensor::fit_kpi_model(seqs, fit);
    model.source = "lidar-calibrate: KITTI tracking label_02 vs " + detector +
                   " detections (AB3DMOT layout), sequences" + used + "; match: same class, score > " +
                   std::to_string(fit.min_score) + ", " + std::to_string(fit.gate) + " m BEV gate, Hungarian";
    const fs::path out = args["out"].as<std::string>();
    sensor::save_kpi_model(model, out);

    const auto measured = sensor::measure_calibration_stats(seqs, fit);
    const auto simulated = sensor::measure_calibration_stats(
        sensor::resimulate(seqs, model, args["seed"].as<std::uint64_t>()), fit);
    std::string report = "# KPI model calibration: measured vs re-simulated on the same ground truth\n\n";
    report += "Sequences:" + used + " (" + std::to_string(measured.frames) + " frames). Model: " + out.string() + "\n";
    report += sensor::format_comparison(measured, simulated);
    std::cout << report;
    if (args.count("report")) write_file_atomically(args["report"].as<std::string>(), report);
    std::cerr << "wrote " << out << "\n";
    return 0;
  } catch (const std::exception& e) {
    std::cerr << "error: " << e.what() << "\n";
    return 1;
  }
}
