// lidar-infer: run the trained models.
//   predict  intensity for recorded scans (SemanticKITTI, KITTI object, or one .bin)
//   sim      the simulation pipeline over a scenario (object list, lanes, point cloud, images)
//   osi      the sensor model behind ASAM OSI: SensorView trace in, SensorData trace out
#include <cstdio>
#include <chrono>
#include <cstring>
#include <filesystem>
#include <iostream>
#include <string>

#include <omp.h>

#include <cxxopts.hpp>

#include "common/atomic_file.h"
#include "common/error.h"
#include "common/progress.h"
#include "infer/intensity_spread_terms.h"
#include "infer/osi_command.h"
#include "infer/scan_prediction.h"
#include "infer/frame_writer.h"
#include "infer/sim_outputs.h"
#include "infer/sim_pipeline.h"
#include "nn/precision.h"
#include "sensor/range_noise.h"

namespace {

void usage() {
  std::cout << "usage: lidar-infer <command> [options]\n"
               "commands:\n"
               "  predict   predicted intensity for recorded scans: point clouds (PCD/PLY), PNG figures, summary\n"
               "  sim       simulate a scenario: object lists, lanes, point clouds with intensity, images, timings\n"
               "            (no options: the bundled demo scenario and models into out/sim)\n"
               "  osi       ASAM OSI: a trace of osi3.SensorView in, osi3.SensorData out (files or stdin/stdout)\n"
               "  osi-trace a scenario JSON as an OSI SensorView trace (to try 'osi' without a simulator)\n"
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
    ("sample-intensity", "with a spread head (lidar-train --heads mean,log_scale_...): draw each cell's intensity from the "
     "predicted distribution, seeded by --seed, scan index and cell, clamped to 0..1 (default: the mean)")
    ("seed", "seed of --sample-intensity", cxxopts::value<std::uint64_t>()->default_value("1"))
    ("spread-terms", "with --sample-intensity: factors on the sampled spread (lidar-qualify loop intensity-spread --out-terms)",
     cxxopts::value<std::string>())
    ("threads", "OpenMP threads", cxxopts::value<int>()->default_value("2"))
    ("precision", "UNet inference precision: fp32, or bf16 (3x3 convolutions in bf16 with fp32 sums, where the CPU has "
     "AVX-512 BF16; else fp32 with a note). Default: LIDARSIM_INFER_PRECISION, else fp32", cxxopts::value<std::string>())
    ("kernels", "how each 3x3 conv's kernel is chosen: rule (the fixed rules in code; the default) or "
     "calibrated (time the candidates this CPU has the first time a layer shape runs here, cached in "
     "$LIDARSIM_KERNEL_CACHE or ~/.cache/lidarsim)",
     cxxopts::value<std::string>()->default_value("rule"))
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
  o.sample_intensity = args.count("sample-intensity") > 0;
  o.seed = args["seed"].as<std::uint64_t>();
  if (args.count("spread-terms")) o.spread_terms = args["spread-terms"].as<std::string>();
  if (args.count("seed") && !o.sample_intensity)
    throw Error("lidar-infer predict: --seed only seeds --sample-intensity (the mean needs no seed)");
  if (o.max_frames < 0) throw Error("lidar-infer predict: --max-frames must be >= 0, got " + std::to_string(o.max_frames));
  if (args["threads"].as<int>() < 1 || args["threads"].as<int>() > 1024)
    throw Error("lidar-infer predict: --threads must be in [1, 1024], got " + std::to_string(args["threads"].as<int>()));
  omp_set_num_threads(args["threads"].as<int>());
  if (args.count("precision"))
    nn::set_inference_precision(nn::parse_inference_precision(args["precision"].as<std::string>(), "lidar-infer predict: --precision"));
  o.kernels = nn::parse_plan_mode(args["kernels"].as<std::string>(), "lidar-infer predict: --kernels");
  const auto summary = infer::predict_scans(o);
  std::printf("%zu scans: MAE %.4f RMSE %.4f over %ld cells, %.3f s per scan (%s); outputs in %s (summary.md)\n",
              summary.scans.size(), summary.mae, summary.rmse, summary.cells, summary.seconds_per_scan,
              nn::to_string(nn::effective_inference_precision()), o.out.c_str());
  return 0;
}


// A bundled default (relative path): the current directory first, then the source tree.
std::filesystem::path resolve_default(const std::string& relative) {
  if (std::filesystem::exists(relative)) return relative;
  const std::filesystem::path in_source = std::filesystem::path(LIDARSIM_SOURCE_DIR) / relative;
  return std::filesystem::exists(in_source) ? in_source : std::filesystem::path(relative);
}

cxxopts::Options sim_options_spec() {
  cxxopts::Options options("lidar-infer sim",
                           "Run a scenario through the sensor model (frames, FoV, occlusion, tracking, KPI errors),\n"
                           "the PCL generator and the intensity UNet. Per frame under --out: objects_NNNN.csv|json,\n"
                           "lanes_NNNN.json, cloud_NNNN.pcd|ply, pgm_NNNN.png, bev_NNNN.png; at the end summary.json\n"
                           "and summary.md (time per stage, real-time factor). Defaults: the bundled scenario and models.");
  // clang-format off
  options.add_options()
    ("scenario", "scenario JSON", cxxopts::value<std::string>()->default_value("data/scenarios/demo_urban.json"))
    ("model", "intensity checkpoint from lidar-train", cxxopts::value<std::string>()->default_value("data/models/intensity_unet.h5"))
    ("kpi", "KPI error model (lidar-calibrate)", cxxopts::value<std::string>()->default_value("data/models/kpi_pointrcnn.json"))
    ("out", "output folder", cxxopts::value<std::string>()->default_value("out/sim"))
    ("frames", "at most this many frames (0 = the whole scenario)", cxxopts::value<int>()->default_value("0"))
    ("format", "point cloud format: pcd or ply", cxxopts::value<std::string>()->default_value("pcd"))
    ("threads", "OpenMP threads", cxxopts::value<int>()->default_value("2"))
    ("precision", "UNet inference precision: fp32, or bf16 (3x3 convolutions in bf16 with fp32 sums, where the CPU has "
     "AVX-512 BF16; else fp32 with a note). Default: LIDARSIM_INFER_PRECISION, else fp32", cxxopts::value<std::string>())
    ("kernels", "how each 3x3 conv's kernel is chosen: rule (the fixed rules in code; the default) or "
     "calibrated (time the candidates this CPU has the first time a layer shape runs here, cached in "
     "$LIDARSIM_KERNEL_CACHE or ~/.cache/lidarsim)",
     cxxopts::value<std::string>()->default_value("rule"))
    ("seed", "seed of the KPI noise, --range-noise, --returns and --sample-intensity", cxxopts::value<std::uint64_t>()->default_value("1"))
    ("range-noise", "range noise model JSON (lidar-qualify range-noise, e.g. data/models/range_noise_hdl64e.json): "
     "each return's range scatters along its beam, drawn from --seed, the frame and the cell; default exact ranges",
     cxxopts::value<std::string>())
    ("sample-intensity", "with a spread head (lidar-train --heads mean,log_scale_...): draw each cell's intensity from the "
     "predicted distribution (seed, frame, cell), clamped to 0..1 (default: the mean)")
    ("spread-terms", "with --sample-intensity: factors on the sampled spread (lidar-qualify loop intensity-spread --out-terms)",
     cxxopts::value<std::string>())
    ("no-outputs", "only time the pipeline: write nothing but the summary")
    ("every", "write the outputs of every N-th frame only (the UNet then runs on those frames only)", cxxopts::value<int>()->default_value("1"))
    ("sync-outputs", "write outputs on the pipeline's thread (default: a writer thread)")
    ("sensor", "beam layout JSON of the sensor to simulate (data/sensors/*.json); replaces the scenario's beams",
     cxxopts::value<std::string>())
    ("returns", "return model JSON (data/models/returns_hdl64e.json): beams that meet geometry return with its probability, drawn from --seed, frame and cell (default: every beam returns)",
     cxxopts::value<std::string>())
    ("no-images", "skip the PNG images")
    ("quiet", "no progress bar")
    ("h,help", "show this help");
  // clang-format on
  return options;
}

// `lidar-infer sim`'s options, checked.
struct SimArgs {
  std::filesystem::path scenario, kpi, model;
  lidarsim::infer::SimOutputOptions out;
  lidarsim::infer::SimOptions sim_options;
  bool write = true, sync_outputs = false, quiet = false;
  int threads = 2, max_frames = 0, every = 1;
};

// Checks the options in the order a user meets them; sets the OpenMP threads and the UNet precision.
SimArgs parse_sim_args(const cxxopts::ParseResult& args) {
  using namespace lidarsim;
  if (!args.unmatched().empty()) throw Error("lidar-infer sim: unexpected argument '" + args.unmatched()[0] + "'");
  auto path_of = [&](const char* name) {
    const std::string value = args[name].as<std::string>();
    return args.count(name) ? std::filesystem::path(value) : resolve_default(value);
  };
  SimArgs a;
  a.scenario = path_of("scenario"), a.kpi = path_of("kpi"), a.model = path_of("model");
  a.out.out = args["out"].as<std::string>();
  a.out.format = args["format"].as<std::string>();
  a.out.images = !args.count("no-images");
  if (a.out.format != "pcd" && a.out.format != "ply")
    throw Error("lidar-infer sim: --format must be pcd or ply, got '" + a.out.format + "'");
  a.write = !args.count("no-outputs");
  a.sync_outputs = args.count("sync-outputs") > 0;
  a.quiet = args.count("quiet") > 0;
  a.threads = args["threads"].as<int>();
  if (a.threads < 1 || a.threads > 1024)
    throw Error("lidar-infer sim: --threads must be in [1, 1024], got " + std::to_string(a.threads));
  a.max_frames = args["frames"].as<int>();
  if (a.max_frames < 0)
    throw Error("lidar-infer sim: --frames must be >= 0 (0: the whole scenario), got " + std::to_string(a.max_frames));
  omp_set_num_threads(a.threads);
  if (args.count("precision"))
    nn::set_inference_precision(nn::parse_inference_precision(args["precision"].as<std::string>(), "lidar-infer sim: --precision"));
  a.sim_options.kernels = nn::parse_plan_mode(args["kernels"].as<std::string>(), "lidar-infer sim: --kernels");
  a.sim_options.seed = args["seed"].as<std::uint64_t>();
  if (args.count("range-noise"))
    a.sim_options.range_noise = std::make_shared<const sensor::RangeNoiseModel>(
        sensor::load_range_noise_model(args["range-noise"].as<std::string>()));
  a.sim_options.sample_intensity = args.count("sample-intensity") > 0;
  if (args.count("spread-terms"))
    a.sim_options.spread_terms = infer::load_intensity_spread_terms(args["spread-terms"].as<std::string>()).terms;
  if (args.count("sensor")) a.sim_options.sensor = pgm::BeamLayout::from_file(args["sensor"].as<std::string>());
  if (args.count("returns"))
    a.sim_options.returns = std::make_shared<sensor::ReturnModel>(sensor::ReturnModel::load(args["returns"].as<std::string>()));
  a.every = args["every"].as<int>();
  if (a.every < 1) throw Error("lidar-infer sim: --every must be >= 1, got " + std::to_string(a.every));
  if (!args.count("model") && !std::filesystem::exists(a.model))
    throw input_error(a.model.string(), "file",
                      "the bundled intensity model does not exist (train one with lidar-train, or pass --model)");
  return a;
}

// What the frame loop took: its wall time and (with a writer thread) the writer's busy time.
struct SimLoopTimes {
  double loop_s = 0, writer_ms = 0;
  bool writer = false;
};

// Runs `frames` frames, writing the outputs (on a writer thread unless asked otherwise) into stats.
SimLoopTimes run_sim_frames(lidarsim::infer::SimPipeline& pipeline, const SimArgs& a, int frames,
                            lidarsim::infer::SimStats& stats) {
  using namespace lidarsim;
  infer::SimFrame frame;
  ProgressBar bar("sim", frames, !a.quiet);
  // Outputs go to a writer thread unless asked otherwise; its time is not the pipeline's.
  std::unique_ptr<infer::FrameWriter> writer;
  if (a.write && !a.sync_outputs) writer = std::make_unique<infer::FrameWriter>(a.out);
  const auto loop0 = std::chrono::steady_clock::now();
  for (int k = 0; k < frames; ++k) {
    // The predicted intensity is read only by the outputs: with --every N the UNet runs on the
    // frames that are written (without outputs it runs on all, so the timing covers it).
    const bool written = a.write && k % a.every == 0;
    pipeline.run_frame(k, frame, written || !a.write);
    double output_ms = 0;
    if (written) {
      if (writer) writer->push(frame);
      else output_ms = infer::write_frame_outputs(a.out, frame);
    }
    stats.add(frame, output_ms);
    char status[96];
    std::snprintf(status, sizeof status, "%.1f ms/frame, %zu objects, %zu points", frame.total_ms,
                  frame.reported.size(), frame.cloud.size());
    bar.update(k + 1, status);
  }
  SimLoopTimes t;
  t.writer = writer != nullptr;
  t.writer_ms = writer ? writer->finish() : 0.0;
  if (writer) stats.set_writer_ms(writer->frame_ms());
  t.loop_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - loop0).count();
  bar.finish();
  return t;
}

// summary.json/.md, then the two lines on stdout.
void report_sim(const SimArgs& a, const lidarsim::infer::SimPipeline& pipeline, lidarsim::infer::SimStats& stats,
                int frames, const SimLoopTimes& t, double wall_seconds) {
  using namespace lidarsim;
  infer::SimStats::Info info;
  info.scenario = a.scenario.string();
  info.kpi_model = a.kpi.string();
  info.intensity_model = a.model.string();
  info.format = a.out.format;
  info.rate_hz = pipeline.scenario().rate_hz;
  info.threads = a.threads;
  info.seed = a.sim_options.seed;
  info.outputs = a.write;
  info.images = a.out.images;
  info.wall_seconds = wall_seconds;
  stats.write_summary(a.out.out, info);
  std::printf("%d frames: %.1f ms per frame (p95 %.1f), real-time factor %.2f on %d thread(s); outputs in %s "
              "(summary.md)\n",
              stats.frames(), stats.mean_total_ms(), stats.p95_total_ms(), stats.real_time_factor(info.rate_hz),
              a.threads, a.out.out.string().c_str());
  // The rate a user sees: the whole loop including any wait for outputs.
  std::printf("loop: %.2f frames/s over %.2f s (outputs %s, every %d frame(s)%s)\n", frames / std::max(t.loop_s, 1e-9),
              t.loop_s, a.write ? (t.writer ? "on a writer thread" : "on the pipeline thread") : "off", a.every,
              t.writer ? (", writer busy " + std::to_string(static_cast<int>(t.writer_ms)) + " ms").c_str() : "");
}

int run_sim(int argc, char** argv) {
  using namespace lidarsim;
  cxxopts::Options options = sim_options_spec();
  const auto args = options.parse(argc, argv);
  if (args.count("help")) {
    std::cout << options.help() << "\n";
    return 0;
  }
  const SimArgs a = parse_sim_args(args);
  const auto wall0 = std::chrono::steady_clock::now();
  infer::SimPipeline pipeline = infer::SimPipeline::from_files(a.scenario, a.kpi, a.model, a.sim_options);
  if (const auto* m = pipeline.intensity_model(); m && !(m->layout() == pipeline.scenario().sensor.beams.layout()))
    std::fprintf(stderr, "warning: %s was trained for another beam layout than the scenario's sensor: %s (model vs scenario)\n",
                 a.model.string().c_str(), m->layout().difference(pipeline.scenario().sensor.beams.layout()).c_str());
  int frames = pipeline.frame_count();
  if (a.max_frames > 0) frames = std::min(frames, a.max_frames);
  std::filesystem::create_directories(a.out.out);
  remove_stale_temp_files_in(a.out.out);  // left by a run that was killed while writing
  infer::SimStats stats;
  const SimLoopTimes t = run_sim_frames(pipeline, a, frames, stats);
  report_sim(a, pipeline, stats, frames, t,
             std::chrono::duration<double>(std::chrono::steady_clock::now() - wall0).count());
  if (const auto* m = pipeline.intensity_model()) {  // the kernels the UNet took, on one line
    std::string choices;
    for (const auto& [k, e] : m->kernel_plan().entries())
      choices += std::string(choices.empty() ? "" : "; ") + nn::to_string(k.pass) + " n" + std::to_string(k.n) + " " +
                 std::to_string(k.ci) + "->" + std::to_string(k.co) + " " + std::to_string(k.h) + "x" +
                 std::to_string(k.w) + ": " + nn::to_string(e.algo);
    std::fprintf(stderr, "lidar-infer sim: kernels %s (%s): %s\n", nn::to_string(m->kernel_plan().mode()),
                 nn::to_string(nn::active_isa()), choices.c_str());
  }
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
    if (command == "sim") return run_sim(argc - 1, argv + 1);
    if (command == "osi") return lidarsim::infer::run_osi_command(argc - 1, argv + 1, resolve_default);
    if (command == "osi-trace") return lidarsim::infer::run_osi_trace_command(argc - 1, argv + 1, resolve_default);
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
