// What reading one frame costs a lazy training step (it must stay small beside the step): a dataset's frames read through
// data::FrameSource (hyperslabs of one chunk each, decompressed and checksummed), then one
// training sample cut from each (crop placed, encoded). Wall and CPU milliseconds per frame.
//   bench_frame_read --data sk.h5 [--passes 20] [--crop 256] [--channels range,class,material]
#include <sys/resource.h>

#include <chrono>
#include <cstdio>
#include <cxxopts.hpp>
#include <sstream>

#include "data/frame_source.h"
#include "train/frame_batches.h"

using namespace lidarsim;

namespace {
double cpu_seconds() {
  rusage u{};
  getrusage(RUSAGE_SELF, &u);
  return u.ru_utime.tv_sec + u.ru_stime.tv_sec + 1e-6 * (u.ru_utime.tv_usec + u.ru_stime.tv_usec);
}
}  // namespace

int main(int argc, char** argv) {
  cxxopts::Options opts("bench_frame_read", "Cost of reading frames one at a time, as lazy training does.");
  opts.add_options()("data", "dataset (HDF5)", cxxopts::value<std::string>())(
      "passes", "passes over the frames", cxxopts::value<int>()->default_value("20"))(
      "crop", "crop width of the sample (0: whole scans)", cxxopts::value<int>()->default_value("256"))(
      "channels", "encoder input channels", cxxopts::value<std::string>()->default_value("range,class,material"))(
      "h,help", "show this help");
  const auto args = opts.parse(argc, argv);
  if (args.count("help") || !args.count("data")) {
    std::printf("%s\n", opts.help().c_str());
    return args.count("help") ? 0 : 2;
  }
  pgm::EncoderConfig encoder;
  encoder.channels.clear();
  std::stringstream list(args["channels"].as<std::string>());
  for (std::string c; std::getline(list, c, ',');) encoder.channels.push_back(c);
  const auto source = data::open_frame_source(args["data"].as<std::string>());
  const int passes = args["passes"].as<int>(), n = source->size();
  const int width = args["crop"].as<int>() > 0 ? args["crop"].as<int>() : source->cols();

  auto time = [&](auto&& body) {
    const auto t0 = std::chrono::steady_clock::now();
    const double c0 = cpu_seconds();
    for (int p = 0; p < passes; ++p)
      for (int f = 0; f < n; ++f) body(f);
    const double wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    return std::pair{1e3 * wall / (passes * n), 1e3 * (cpu_seconds() - c0) / (passes * n)};
  };
  double checksum = 0;
  const auto [read_wall, read_cpu] = time([&](int f) { checksum += source->frame(f).target[0]; });
  const train::TrainingFrames frames({source.get()}, encoder, std::nullopt);
  nn::Tensor x(1, encoder.input_channels(), source->rows(), width), y(1, 1, source->rows(), width),
      m(1, 1, source->rows(), width);
  const auto [sample_wall, sample_cpu] = time([&](int f) { frames.fill({f, 17 * f, f % 2 == 1}, x, y, m, 0); });
  std::printf("%d frames (%d x %d, %d channels) x %d passes: read %.2f ms/frame (CPU %.2f); read + crop %d + encode "
              "%.2f ms/sample (CPU %.2f) [%g]\n",
              n, source->rows(), source->cols(), static_cast<int>(source->header().channels.size()), passes, read_wall,
              read_cpu, width, sample_wall, sample_cpu, checksum > -1 ? 0.0 : 1.0);
  return 0;
}
