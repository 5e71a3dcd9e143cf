// Streaming import throughput (time linear in the scans, memory flat): the bundled SemanticKITTI scan repeated --scans times
// (symlinks in a temporary folder), imported with lidar-data's code path (data::import_to_file)
// on --threads OpenMP threads. Reports scans/s and the process's peak RSS; run it at a few sizes
// to see that time grows linearly and memory not at all:
//   bench_import --scans 200      bench_import --scans 2000
// Each size is imported --runs times; the median run is reported.
#include <omp.h>
#include <sys/resource.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cxxopts.hpp>
#include <filesystem>
#include <string>
#include <vector>

#include "data/import.h"

namespace fs = std::filesystem;
using namespace lidarsim;

int main(int argc, char** argv) {
  cxxopts::Options opts("bench_import", "Streaming import throughput on the bundled scan repeated N times.");
  opts.add_options()("scans", "scans to import", cxxopts::value<int>()->default_value("200"))(
      "threads", "OpenMP threads", cxxopts::value<int>()->default_value("2"))(
      "runs", "repetitions (median reported)", cxxopts::value<int>()->default_value("1"))(
      "keep", "keep the temporary folder and dataset")("h,help", "show this help");
  const auto args = opts.parse(argc, argv);
  if (args.count("help")) {
    std::printf("%s\n", opts.help().c_str());
    return 0;
  }
  const int scans = std::max(1, args["scans"].as<int>());
  omp_set_num_threads(std::max(1, args["threads"].as<int>()));
  const fs::path sample = fs::path(LIDARSIM_SOURCE_DIR) / "data/samples/semantickitti/sequences/00";
  const fs::path dir = fs::temp_directory_path() / ("lidarsim_bench_import_" + std::to_string(::getpid()));
  const fs::path seq = dir / "sequences/00";
  fs::create_directories(seq / "velodyne");
  fs::create_directories(seq / "labels");
  for (int i = 0; i < scans; ++i) {
    char id[16];
    std::snprintf(id, sizeof id, "%06d", i);
    fs::create_symlink(sample / "velodyne/000000.bin", seq / "velodyne" / (std::string(id) + ".bin"));
    fs::create_symlink(sample / "labels/000000.label", seq / "labels" / (std::string(id) + ".label"));
  }
  std::vector<double> seconds;
  data::ImportSummary summary;
  for (int r = 0; r < std::max(1, args["runs"].as<int>()); ++r) {
    const auto t0 = std::chrono::steady_clock::now();
    summary = data::import_to_file(data::SourceFormat::SemanticKitti, dir, dir / "out.h5", {});
    seconds.push_back(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
  }
  std::sort(seconds.begin(), seconds.end());
  const double s = seconds[seconds.size() / 2];
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  double load[3] = {0, 0, 0};
  getloadavg(load, 3);
  std::printf("import %d scans (%d x %d, %zu channels) on %d thread(s): %.2f s, %.2f scans/s, file %.1f MB, "
              "peak RSS %.0f MB (load average %.1f)\n",
              summary.frames, summary.layout.rows(), summary.layout.columns, summary.channels.size(),
              omp_get_max_threads(), s, summary.frames / s, fs::file_size(dir / "out.h5") / 1e6,
              usage.ru_maxrss / 1024.0, load[0]);
  if (!args.count("keep")) fs::remove_all(dir);
  return 0;
}
