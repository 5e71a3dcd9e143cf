#include "infer/osi_command.h"

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <fstream>
#include <iostream>
#include <memory>
#include <vector>

#include <omp.h>

#include <cxxopts.hpp>

#include "common/atomic_file.h"
#include "common/error.h"
#include "infer/osi_runner.h"
#include "osi/osi3_subset.pb.h"
#include "osi/scenario_trace.h"
#include "osi/sensor_view_decoder.h"
#include "osi/trace.h"

namespace lidarsim::infer {

namespace {

// Output to a file goes through a temporary sibling renamed at the end (nothing torn is left
// behind on an error); "-" is stdout.
class OutputTrace {
 public:
  explicit OutputTrace(const std::string& path) {
    if (path == "-") {
      out_ = &std::cout;
      return;
    }
    if (const auto parent = std::filesystem::path(path).parent_path(); !parent.empty())
      std::filesystem::create_directories(parent);
    atomic_ = std::make_unique<AtomicFile>(path);
    file_.open(atomic_->temp_path(), std::ios::binary);
    if (!file_) throw Error(path + ": cannot be written");
    out_ = &file_;
  }
  std::ostream& stream() { return *out_; }
  void commit() {
    if (!atomic_) return;
    file_.close();
    if (!file_) throw Error(atomic_->final_path().string() + ": write failed");
    atomic_->commit();
  }

 private:
  std::unique_ptr<AtomicFile> atomic_;
  std::ofstream file_;
  std::ostream* out_ = nullptr;
};

// What a run of frames took: per frame, from message read to SensorData written, and the model's
// own stages; objects and lidar detections reported over all frames (every detector).
struct StreamStats {
  std::vector<double> latency_ms, model_ms;
  std::size_t detections = 0, objects = 0;
};

// Frame after frame until the input ends, each flushed as soon as it is written.
StreamStats stream_frames(OsiRunner& runner, osi::TraceReader& reader, osi::TraceWriter& writer, osi::TraceFormat format,
                          const std::string& source) {
  std::string bytes;            // one SensorView as it arrived
  osi::msg::SensorView view;    // decoded by hand (osi/sensor_view_decoder.h)
  osi3::SensorData data;  // the text format only: binary output is encoded straight to bytes
  std::string framed;     // length field + SensorData, reused from frame to frame
  StreamStats st;
  using clock = std::chrono::steady_clock;
  while (reader.next(bytes)) {
    const auto t0 = clock::now();  // message in hand: from here to flushed output is our latency
    osi::decode_sensor_view(bytes, source, reader.index(), view);
    if (format == osi::TraceFormat::Binary) {
      runner.step(view, reader.index(), source, framed, osi::kLengthBytes);
      writer.write_framed(framed);
    } else {
      runner.step(view, reader.index(), source, data);
      writer.write(data);
    }
    st.latency_ms.push_back(std::chrono::duration<double, std::milli>(clock::now() - t0).count());
    st.model_ms.push_back(runner.last_frame().total_ms);
    st.objects += runner.reported_objects();
    st.detections += runner.reported_points();
  }
  return st;
}

void print_stream_summary(const StreamStats& st, const std::string& out_path) {
  std::vector<double> sorted = st.latency_ms;
  std::sort(sorted.begin(), sorted.end());
  double mean = 0, model = 0;
  for (double v : st.latency_ms) mean += v;
  for (double v : st.model_ms) model += v;
  const std::size_t n = st.latency_ms.size();
  std::fprintf(stderr,
               "%zu frames: %.1f ms per frame from message read to SensorData written (median %.1f, p95 %.1f; "
               "model stages %.1f); %.1f objects and %.0f lidar detections per frame -> %s\n",
               n, mean / n, sorted[n / 2], sorted[std::min(n - 1, n * 95 / 100)], model / n,
               static_cast<double>(st.objects) / n, static_cast<double>(st.detections) / n,
               out_path == "-" ? "stdout" : out_path.c_str());
}

}  // namespace

int run_osi_command(int argc, char** argv, const DefaultResolver& resolve) {
  cxxopts::Options options(
      "lidar-infer osi",
      "Run an ASAM OSI trace through the sensor model: a single-channel binary trace of osi3.SensorView\n"
      "(each message preceded by its 4-byte little-endian length) in, one osi3.SensorData per frame out\n"
      "(objects, lane boundaries, the point cloud with predicted intensity as lidar detections).\n"
      "'-' reads stdin / writes stdout frame by frame (flushed per frame) for a co-simulation pipe.\n"
      "The sensor's beams, field of view and range come from --scenario's sensor block; the mount from\n"
      "each SensorView's mounting_position.");
  // clang-format off
  options.add_options()
    ("in", "input trace of osi3.SensorView ('-' = stdin)", cxxopts::value<std::string>())
    ("out", "output trace of osi3.SensorData ('-' = stdout)", cxxopts::value<std::string>())
    ("format", "output format: binary (length-prefixed) or txth (protobuf text, for people)", cxxopts::value<std::string>()->default_value("binary"))
    ("scenario", "scenario JSON whose sensor block (beams, fov, range) is used", cxxopts::value<std::string>()->default_value("data/scenarios/demo_urban.json"))
    ("model", "intensity checkpoint from lidar-train", cxxopts::value<std::string>()->default_value("data/models/intensity_unet.h5"))
    ("kpi", "KPI error model (lidar-calibrate)", cxxopts::value<std::string>()->default_value("data/models/kpi_pointrcnn.json"))
    ("seed", "seed of the KPI noise", cxxopts::value<std::uint64_t>()->default_value("1"))
    ("threads", "OpenMP threads", cxxopts::value<int>()->default_value("2"))
    ("no-point-cloud", "object-level model only: no PCL generator, UNet or lidar detections")
    ("ideal", "no KPI errors, misses, false positives or heading flips, tracks confirmed on their first frame")
    ("quiet", "no summary on stderr")
    ("h,help", "show this help");
  // clang-format on
  const auto args = options.parse(argc, argv);
  if (args.count("help")) {
    std::cout << options.help() << "\n";
    return 0;
  }
  if (!args.unmatched().empty()) throw Error("lidar-infer osi: unexpected argument '" + args.unmatched()[0] + "'");
  if (!args.count("in") || !args.count("out")) throw Error("lidar-infer osi: --in and --out are required (see --help)");
  const std::string in_path = args["in"].as<std::string>(), out_path = args["out"].as<std::string>();
  const osi::TraceFormat format = osi::trace_format_from_string(args["format"].as<std::string>());
  auto path_of = [&](const char* name) {
    const std::string value = args[name].as<std::string>();
    return args.count(name) ? std::filesystem::path(value) : resolve(value);
  };
  SimOptions sim;
  sim.seed = args["seed"].as<std::uint64_t>();
  if (args.count("no-point-cloud")) sim.point_cloud = sim.intensity = false;
  if (args.count("ideal")) make_ideal(sim);
  omp_set_num_threads(std::max(1, args["threads"].as<int>()));

  std::ifstream file;
  std::istream* in = &std::cin;
  const std::string source = in_path == "-" ? std::string("stdin") : in_path;
  if (in_path != "-") {
    file.open(in_path, std::ios::binary);
    if (!file) throw Error(in_path + ": cannot be opened");
    in = &file;
  }
  OsiRunner runner = OsiRunner::from_files(path_of("scenario"), path_of("kpi"), path_of("model"), sim);
  if (const auto* m = runner.intensity_model(); m && !(m->layout() == runner.sensor().beams.layout()))
    std::fprintf(stderr, "warning: the intensity model was trained for the beam layout '%s', the sensor is '%s'\n",
                 m->layout().name.c_str(), runner.sensor().beams.layout().name.c_str());

  OutputTrace output(out_path);
  osi::TraceReader reader(*in, source);
  osi::TraceWriter writer(output.stream(), format);
  const StreamStats st = stream_frames(runner, reader, writer, format, source);
  if (reader.index() < 0) throw Error(source + ": no message (an empty trace)");
  output.commit();
  if (!args.count("quiet")) print_stream_summary(st, out_path);
  return 0;
}

int run_osi_trace_command(int argc, char** argv, const DefaultResolver& resolve) {
  cxxopts::Options options("lidar-infer osi-trace",
                           "Write a scenario JSON as a single-channel binary OSI trace of osi3.SensorView, one per\n"
                           "frame (host vehicle, moving objects, lane boundaries, mounting position), for trying\n"
                           "'lidar-infer osi' and the OSI FMU without a simulator.");
  // clang-format off
  options.add_options()
    ("scenario", "scenario JSON", cxxopts::value<std::string>()->default_value("data/scenarios/demo_urban.json"))
    ("out", "output trace ('-' = stdout)", cxxopts::value<std::string>())
    ("format", "binary or txth", cxxopts::value<std::string>()->default_value("binary"))
    ("frames", "at most this many frames (0 = the whole scenario)", cxxopts::value<int>()->default_value("0"))
    ("h,help", "show this help");
  // clang-format on
  const auto args = options.parse(argc, argv);
  if (args.count("help")) {
    std::cout << options.help() << "\n";
    return 0;
  }
  if (!args.unmatched().empty())
    throw Error("lidar-infer osi-trace: unexpected argument '" + args.unmatched()[0] + "'");
  if (!args.count("out")) throw Error("lidar-infer osi-trace: --out is required (see --help)");
  const std::string value = args["scenario"].as<std::string>();
  const std::filesystem::path scenario_path = args.count("scenario") ? std::filesystem::path(value) : resolve(value);
  const osi::TraceFormat format = osi::trace_format_from_string(args["format"].as<std::string>());
  const sensor::Scenario scenario = sensor::read_scenario(scenario_path);
  int frames = scenario.frame_count();
  if (args["frames"].as<int>() > 0) frames = std::min(frames, args["frames"].as<int>());
  const std::string out_path = args["out"].as<std::string>();
  OutputTrace output(out_path);
  osi::TraceWriter writer(output.stream(), format);
  osi3::SensorView view;
  for (int k = 0; k < frames; ++k) {
    osi::sensor_view_from_scenario(scenario, scenario.frame_time(k), view);
    writer.write(view);
  }
  output.commit();
  if (out_path != "-") std::fprintf(stderr, "%d SensorView messages -> %s\n", frames, out_path.c_str());
  return 0;
}

}  // namespace lidarsim::infer
