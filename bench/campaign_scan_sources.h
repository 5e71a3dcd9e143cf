#pragma once
// The measured geometry the intensity campaigns plant on (bench_loop_campaign_intensity,
// bench_loop_campaign_intensity_spread): SemanticKITTI sequence 00, nuScenes-lidarseg and
// RELLIS-3D from ../shared/data, imported with the channels the loops read.
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <string>
#include <vector>

#include "common/error.h"
#include "data/class_table.h"
#include "data/import.h"
#include "data/nuscenes_lidarseg.h"
#include "qualify/intensity/intensity.h"

namespace lidarsim::bench {

namespace fs = std::filesystem;

// The channels the loop reads (qualify/intensity.cpp kLoopChannels); intensity_cells names any missing one.
inline const std::vector<std::string> kLoopChannels = {"elevation", "azimuth", "height", "incidence", "depth_discontinuity"};

struct Source {
  std::string name;
  data::Dataset geometry;
};

inline std::vector<Source> load_sources(const std::string& which, const fs::path& shared, const fs::path& source_dir) {
  std::vector<std::string> names = which == "mixed" ? std::vector<std::string>{"semantickitti", "nuscenes", "rellis"}
                                                    : std::vector<std::string>{which};
  std::vector<Source> out;
  data::ImportOptions opt;
  opt.extra_channels = kLoopChannels;
  for (const auto& name : names) {
    const auto t0 = std::chrono::steady_clock::now();
    if (name == "semantickitti") {
      out.push_back({name, qualify::import_for_qualify(shared / "semantickitti-seq00-sample")});
    } else if (name == "nuscenes") {
      const auto layout = pgm::BeamLayout::from_file((source_dir / "data/sensors/hdl32e-nuscenes.json").string());
      const auto table = data::read_class_table(source_dir / "data/ontologies/nuscenes-lidarseg.csv");
      out.push_back({name, data::import_nuscenes_lidarseg(shared / "nuscenes-lidarseg-scene", layout, table, opt)});
    } else if (name == "rellis") {
      data::ImportOptions r = opt;
      r.layout = pgm::BeamLayout::from_file((source_dir / "data/sensors/os1-64-rellis3d.json").string());
      r.class_table = source_dir / "data/ontologies/rellis3d.csv";
      out.push_back({name, data::import_dataset(data::SourceFormat::Rellis3d, shared / "rellis3d-os1-sample", r)});
    } else {
      throw Error("--data '" + name + "': unknown (expected semantickitti, nuscenes, rellis or mixed)");
    }
    const auto& g = out.back().geometry;
    std::fprintf(stderr, "loaded %s: %d frames, %d x %d, %.1f s\n", name.c_str(), g.size(), g.rows(), g.cols(),
                 std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
  }
  return out;
}

}  // namespace lidarsim::bench
