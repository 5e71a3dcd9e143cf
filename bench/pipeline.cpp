// Simulation pipeline frame rate, and what each part of a frame costs:
//   1. the whole pipeline (scenario sampling, frames, FoV, occlusion, tracking, KPI manager, lanes,
//      PCL generator into a 64 x 1024 PGM, UNet intensity inference, point cloud), writing
//      outputs excluded, on --threads (2) over the bundled demo scenario: frames/s, target >= 10;
//   2. the object-level model alone (frames, FoV, occlusion, tracking, KPI manager) on a synthetic
//      in-memory scenario with 100 objects: frames/s, target >= 1000;
//   3. (--only outputs) the loop of `lidar-infer sim --every N`: the whole pipeline with the outputs
//      of every N-th frame written by the writer thread into a temporary folder, wall and CPU time;
//   4. (--digest) FNV-1a digests of everything the runs compute (object lists, visible fractions,
//      PGM channels, point cloud), to show that a faster build computes the same numbers.
// The intensity model is data/models/intensity_unet.h5 when present, else an untrained unet-ref
// (base 16, depth 4, the default encoder's input channels): the cost does not depend on weights.
// Each measurement is repeated --runs times; the median run is reported (and the fastest).
#include <omp.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <cxxopts.hpp>
#include <filesystem>
#include <functional>
#include <memory>
#include <numbers>
#include <random>
#include <set>
#include <sstream>
#include <string>
#include <time.h>
#include <unistd.h>
#include <vector>

#include <nlohmann/json.hpp>

#include "common/atomic_file.h"
#include "infer/frame_writer.h"
#include "infer/sim_outputs.h"
#include "infer/sim_pipeline.h"
#include "nn/checkpoint.h"
#include "sensor/kpi_model.h"
#include "sensor/scenario.h"
#include "bench/synthetic_scenario.h"

using namespace lidarsim;
namespace fs = std::filesystem;

namespace {

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  const std::size_t n = v.size();
  return n == 0 ? 0 : n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

struct RunResult {
  double fps = 0;
  std::array<double, infer::kNumSimStages> stage_ms{};
  double ms_per_frame = 0;
  double objects_in_view = 0, reported = 0, points = 0;
  double cpu_ms_per_frame = 0;  // process CPU time (all threads): what the run cost without waiting for a core
  double thread_cpu_ms_per_frame = 0;  // CPU time of the calling thread alone (without OpenMP workers, writer)
  double loop_fps = 0;                 // frames over the wall time of the whole loop (outputs run)
  double writer_cpu_ms = 0, writer_ms = 0;  // per written frame: writer thread CPU, wall
};

double clock_seconds(clockid_t id) {
  timespec ts{};
  clock_gettime(id, &ts);
  return ts.tv_sec + 1e-9 * ts.tv_nsec;
}
double process_cpu_seconds() { return clock_seconds(CLOCK_PROCESS_CPUTIME_ID); }
double thread_cpu_seconds() { return clock_seconds(CLOCK_THREAD_CPUTIME_ID); }

void finish_result(RunResult& r, const infer::SimStats& stats) {
  r.ms_per_frame = stats.mean_total_ms();
  r.fps = 1000.0 / r.ms_per_frame;
  for (int s = 0; s < infer::kNumSimStages; ++s) r.stage_ms[s] = stats.mean_ms(s);
  const auto j = nlohmann::json::parse(stats.to_json({}));
  r.objects_in_view = j["per_frame_mean"]["objects_in_view"];
  r.reported = j["per_frame_mean"]["objects_reported"];
  r.points = j["per_frame_mean"]["points"];
}

RunResult run_once(infer::SimPipeline& pipeline, int frames) {
  infer::SimFrame frame;
  infer::SimStats stats;
  const double cpu0 = process_cpu_seconds(), th0 = thread_cpu_seconds();
  for (int k = 0; k < frames; ++k) {
    pipeline.run_frame(k, frame);
    stats.add(frame);
  }
  RunResult r;
  r.cpu_ms_per_frame = 1000 * (process_cpu_seconds() - cpu0) / frames;
  r.thread_cpu_ms_per_frame = 1000 * (thread_cpu_seconds() - th0) / frames;
  finish_result(r, stats);
  return r;
}

// The loop of `lidar-infer sim --every N` (infer/lidar_infer_main.cpp): outputs of every N-th
// frame go to the writer thread; the UNet runs only on those frames unless intensity_every_frame.
RunResult run_outputs(infer::SimPipeline& pipeline, int frames, int every, const fs::path& dir, bool intensity_every_frame) {
  infer::SimOutputOptions out;
  out.out = dir;
  fs::create_directories(dir);
  infer::SimFrame frame;
  infer::SimStats stats;
  const auto wall0 = std::chrono::steady_clock::now();
  const double cpu0 = process_cpu_seconds(), th0 = thread_cpu_seconds();
  RunResult r;
  {
    infer::FrameWriter writer(out);
    for (int k = 0; k < frames; ++k) {
      const bool written = k % every == 0;
      pipeline.run_frame(k, frame, intensity_every_frame || written);
      if (written) writer.push(frame);
      stats.add(frame);
    }
    writer.finish();
    for (double ms : writer.frame_cpu_ms()) r.writer_cpu_ms += ms / writer.frame_cpu_ms().size();
    for (double ms : writer.frame_ms()) r.writer_ms += ms / writer.frame_ms().size();
  }
  const double wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - wall0).count();
  r.cpu_ms_per_frame = 1000 * (process_cpu_seconds() - cpu0) / frames;
  r.thread_cpu_ms_per_frame = 1000 * (thread_cpu_seconds() - th0) / frames;
  r.loop_fps = frames / std::max(wall, 1e-9);
  finish_result(r, stats);
  return r;
}

// FNV-1a over the bytes of everything a frame carries that outputs are made of.
struct Digest {
  std::uint64_t h = 1469598103934665603ull;
  void bytes(const void* p, std::size_t n) {
    const auto* c = static_cast<const unsigned char*>(p);
    for (std::size_t i = 0; i < n; ++i) h = (h ^ c[i]) * 1099511628211ull;
  }
  template <class T>
  void value(const T& v) { bytes(&v, sizeof v); }
  template <class T>
  void vec(const std::vector<T>& v) { value(v.size()); if (!v.empty()) bytes(v.data(), v.size() * sizeof(T)); }
  void object(const sensor::Object& o) {
    value(o.id);
    value(o.cls);
    bytes(o.material.data(), o.material.size());
    for (const Eigen::Vector3d* v : {&o.position, &o.velocity, &o.acceleration, &o.size}) bytes(v->data(), 3 * sizeof(double));
    for (double d : {o.heading, o.visible_fraction, o.truncation, o.score}) value(d);
  }
  void frame(const infer::SimFrame& f) {
    value(f.index);
    value(f.time);
    for (const auto* fr : {&f.ego, &f.sensor}) {
      value(fr->objects.size());
      for (const auto& o : fr->objects) object(o);
      value(fr->lanes.size());
      for (const auto& l : fr->lanes) {
        value(l.id);
        value(l.type);
        value(l.points.size());
        for (const auto& p : l.points) bytes(p.data(), 3 * sizeof(double));
      }
    }
    value(f.reported.size());
    for (const auto& r : f.reported) {
      object(r.object);
      value(r.truth_id);
      value(r.coasting);
    }
    value(f.lanes.size());
    for (const auto& l : f.lanes)
      for (double d : {l.c0, l.c1, l.c2, l.c3, l.x_min, l.x_max}) value(d);
    for (int n : {f.objects_existing, f.objects_in_view, f.objects_occluded, f.objects_partly_occluded, f.returns}) value(n);
    if (f.pgm.cells() > 0) {
      for (const auto& name : f.pgm.channel_names()) bytes(name.data(), name.size());
      vec(f.pgm.data());
      vec(f.pgm.point_index());
    }
    for (const auto* v : {&f.cloud.x, &f.cloud.y, &f.cloud.z, &f.cloud.intensity, &f.cloud.cls, &f.cloud.material,
                          &f.cloud.object_id, &f.cloud.range})
      vec(*v);
    vec(f.cloud.cell);
  }
};

std::uint64_t digest_run(infer::SimPipeline& pipeline, int frames) {
  infer::SimFrame frame;
  Digest d;
  for (int k = 0; k < frames; ++k) {
    pipeline.run_frame(k, frame);
    d.frame(frame);
  }
  return d.h;
}

void print_stages(const std::vector<RunResult>& runs, bool point_cloud) {
  std::printf("  per stage, ms per frame (median over runs):");
  for (int s = 0; s < infer::kNumSimStages; ++s) {
    const auto st = static_cast<infer::SimStage>(s);
    if (!point_cloud && (st == infer::SimStage::PclGenerator || st == infer::SimStage::Unet ||
                         st == infer::SimStage::PointCloud))
      continue;
    std::vector<double> v;
    for (const auto& r : runs) v.push_back(r.stage_ms[s]);
    std::printf(" %s %.3f", infer::to_string(st), median(v));
  }
  std::printf("\n");
}

template <class F>
double median_of(const std::vector<RunResult>& runs, F f) {
  std::vector<double> v;
  for (const auto& r : runs) v.push_back(f(r));
  return median(v);
}

nlohmann::json stages_json(const std::vector<RunResult>& runs) {
  nlohmann::json j;
  for (int s = 0; s < infer::kNumSimStages; ++s)
    j[infer::to_string(static_cast<infer::SimStage>(s))] = median_of(runs, [&](const RunResult& r) { return r.stage_ms[s]; });
  return j;
}

// The intensity model: bundled, given, or an untrained unet-ref in a temporary file (removed by
// the caller).
struct ModelChoice {
  fs::path path, temp;
  std::string note;
};

ModelChoice choose_model(const cxxopts::ParseResult& args, const fs::path& src) {
  ModelChoice m;
  if (args.count("model")) {
    m.path = args["model"].as<std::string>();
    m.note = "given";
  } else if (fs::exists(src / "data/models/intensity_unet.h5")) {
    m.path = src / "data/models/intensity_unet.h5";
    m.note = "bundled";
  } else {
    m.temp = fs::temp_directory_path() / ("bench_pipeline_unet_ref_" + std::to_string(::getpid()) + ".h5");
    infer::write_untrained_checkpoint(m.temp, 16, 4, 1, pgm::BeamLayout::hdl64e());
    m.path = m.temp;
    m.note = "untrained unet-ref (no bundled model yet)";
  }
  return m;
}

std::set<std::string> parse_parts(const std::string& list) {
  std::set<std::string> parts;
  std::stringstream ss(list);
  for (std::string p; std::getline(ss, p, ',');) {
    if (p != "whole" && p != "objects" && p != "outputs")
      throw std::runtime_error("--only: unknown part '" + p + "' (whole, objects, outputs)");
    parts.insert(p);
  }
  return parts;
}

// What every part needs: the options read once, and factories for fresh pipelines (fresh
// tracker/KPI state: every run simulates the same frames).
struct Bench {
  int threads = 2, runs = 5, frames_used = 0, n = 100, object_frames = 2000, every = 10;
  ModelChoice model;
  nn::Checkpoint meta;
  std::function<infer::SimPipeline()> whole, objects;
};

// 1. Whole pipeline.
std::string measure_whole(const Bench& b, nlohmann::json& j) {
  std::vector<RunResult> whole;
  for (int r = 0; r < b.runs; ++r) {
    auto p = b.whole();
    whole.push_back(run_once(p, b.frames_used));
  }
  std::vector<double> fps_whole;
  for (const auto& r : whole) fps_whole.push_back(r.fps);
  const double whole_median = median(fps_whole), whole_best = *std::max_element(fps_whole.begin(), fps_whole.end());
  std::printf("whole pipeline: %d frames x %d runs, %d thread(s), PGM 64 x 1024, UNet base %d depth %d in %d (%s)\n",
              b.frames_used, b.runs, b.threads, b.meta.unet.base, b.meta.unet.depth, b.meta.unet.in_channels,
              b.model.note.c_str());
  std::printf("  %.1f frames/s median (best %.1f), %.1f ms/frame; %.1f objects in view, %.1f reported, %.0f points per frame\n",
              whole_median, whole_best, 1000 / whole_median, whole.front().objects_in_view, whole.front().reported,
              whole.front().points);
  print_stages(whole, true);
  const double whole_cpu = median_of(whole, [](const RunResult& r) { return r.cpu_ms_per_frame; });
  std::printf("  process CPU time %.1f ms/frame over all threads (>= %.1f ms/frame of wall time on %d free cores)\n",
              whole_cpu, whole_cpu / b.threads, b.threads);
  char row[256];
  std::snprintf(row, sizeof row, "| whole pipeline, %d threads, UNet base %d depth %d, 64 x 1024 | %.1f | <= %.1f | >= 10 | %s |",
                b.threads, b.meta.unet.base, b.meta.unet.depth, whole_median, 1000 * b.threads / whole_cpu,
                whole_median >= 10 ? "yes" : "NO");
  j["whole"] = {{"frames", b.frames_used}, {"fps", whole_median}, {"fps_best", whole_best}, {"cpu_ms_per_frame", whole_cpu},
                {"unet_base", b.meta.unet.base}, {"unet_depth", b.meta.unet.depth}, {"model", b.model.note},
                {"stage_ms", stages_json(whole)}};
  return row;
}

// 2. Object-level model alone.
std::string measure_objects(const Bench& b, nlohmann::json& j) {
  std::vector<RunResult> objects;
  for (int r = 0; r < b.runs; ++r) {
    auto p = b.objects();
    objects.push_back(run_once(p, b.object_frames));
  }
  std::vector<double> fps_objects;
  for (const auto& r : objects) fps_objects.push_back(r.fps);
  const double obj_median = median(fps_objects), obj_best = *std::max_element(fps_objects.begin(), fps_objects.end());
  std::printf("object-level model: %d objects, %d frames x %d runs (sampling, frames, FoV, occlusion, tracking, KPI)\n", b.n,
              b.object_frames, b.runs);
  std::printf("  %.0f frames/s median (best %.0f), %.3f ms/frame; %.1f objects in view, %.1f reported per frame\n",
              obj_median, obj_best, 1000 / obj_median, objects.front().objects_in_view, objects.front().reported);
  print_stages(objects, false);
  const double obj_cpu = median_of(objects, [](const RunResult& r) { return r.cpu_ms_per_frame; });
  std::printf("  process CPU time %.3f ms/frame (the object-level model is serial: %.0f frames/s on a free core)\n", obj_cpu,
              1000 / obj_cpu);
  char row[256];
  std::snprintf(row, sizeof row, "| object-level model, %d objects | %.0f | %.0f | >= 1000 | %s |", b.n, obj_median,
                1000 / obj_cpu, obj_median >= 1000 ? "yes" : "NO");
  j["objects"] = {{"count", b.n}, {"frames", b.object_frames}, {"fps", obj_median}, {"fps_best", obj_best},
                  {"cpu_ms_per_frame", obj_cpu}, {"fps_cpu_bound", 1000 / obj_cpu}, {"stage_ms", stages_json(objects)}};
  return row;
}

// 3. The lidar-infer sim loop with outputs on every N-th frame.
std::string measure_outputs(const Bench& b, bool all, nlohmann::json& j) {
  const fs::path dir = fs::temp_directory_path() / ("bench_pipeline_outputs_" + std::to_string(::getpid()));
  std::vector<RunResult> outs;
  for (int r = 0; r < b.runs; ++r) {
    auto p = b.whole();
    outs.push_back(run_outputs(p, b.frames_used, b.every, dir, all));
    fs::remove_all(dir);
  }
  const double loop = median_of(outs, [](const RunResult& r) { return r.loop_fps; });
  const double cpu = median_of(outs, [](const RunResult& r) { return r.cpu_ms_per_frame; });
  const double th = median_of(outs, [](const RunResult& r) { return r.thread_cpu_ms_per_frame; });
  std::printf("outputs loop (lidar-infer sim --every %d): %d frames x %d runs, %d thread(s), UNet on %s\n", b.every,
              b.frames_used, b.runs, b.threads, all ? "every frame" : "the written frames only");
  std::printf("  %.1f frames/s wall (median), pipeline stages %.2f ms/frame\n", loop,
              median_of(outs, [](const RunResult& r) { return r.ms_per_frame; }));
  print_stages(outs, true);
  const double wcpu = median_of(outs, [](const RunResult& r) { return r.writer_cpu_ms; });
  std::printf("  process CPU time %.2f ms/frame (pipeline thread %.2f; OpenMP workers and writer the rest): "
              "<= %.0f frames/s on %d free cores\n", cpu, th, 1000 * b.threads / cpu, b.threads);
  std::printf("  writer thread: %.1f ms CPU per written frame (%.1f ms wall), %.2f ms CPU per frame\n", wcpu,
              median_of(outs, [](const RunResult& r) { return r.writer_ms; }), wcpu / b.every);
  char row[256];
  std::snprintf(row, sizeof row, "| lidar-infer sim loop, outputs every %d, UNet on %s | %.1f | <= %.0f | >= 150 | %s |", b.every,
                all ? "every frame" : "written frames", loop, 1000 * b.threads / cpu, loop >= 150 ? "yes" : "NO");
  j["outputs"] = {{"every", b.every}, {"unet_every_frame", all}, {"frames", b.frames_used}, {"loop_fps", loop},
                  {"cpu_ms_per_frame", cpu}, {"thread_cpu_ms_per_frame", th}, {"fps_cpu_bound", 1000 * b.threads / cpu},
                  {"writer_cpu_ms_per_written_frame", wcpu},
                  {"stage_ms", stages_json(outs)}};
  return row;
}

cxxopts::Options pipeline_options(const fs::path& src) {
  cxxopts::Options opts("bench_pipeline", "lidar-infer sim frame rate: whole pipeline and object-level model");
  // clang-format off
  opts.add_options()
    ("scenario", "scenario", cxxopts::value<std::string>()->default_value((src / "data/scenarios/demo_urban.json").string()))
    ("kpi", "KPI model", cxxopts::value<std::string>()->default_value((src / "data/models/kpi_pointrcnn.json").string()))
    ("model", "intensity checkpoint (default: the bundled one, else an untrained unet-ref)", cxxopts::value<std::string>())
    ("threads", "OpenMP threads", cxxopts::value<int>()->default_value("2"))
    ("runs", "repetitions of each measurement", cxxopts::value<int>()->default_value("5"))
    ("frames", "frames per run of the whole pipeline (0 = the whole scenario)", cxxopts::value<int>()->default_value("0"))
    ("objects", "objects in the object-level scenario", cxxopts::value<int>()->default_value("100"))
    ("object-frames", "frames per run of the object-level model", cxxopts::value<int>()->default_value("2000"))
    ("only", "parts to run, comma-separated: whole, objects, outputs (the lidar-infer sim --every loop)",
     cxxopts::value<std::string>()->default_value("whole,objects"))
    ("every", "outputs part: write the outputs of every N-th frame", cxxopts::value<int>()->default_value("10"))
    ("intensity-every-frame", "outputs part: run the UNet on every frame, also those not written (by default only written frames run it)")
    ("digest", "print digests of what the runs compute (same numbers <=> same digests), no timing")
    ("json", "also write the results as JSON to this file", cxxopts::value<std::string>())
    ("h,help", "help");
  // clang-format on
  return opts;
}

}  // namespace

int main(int argc, char** argv) {
  const fs::path src = LIDARSIM_SOURCE_DIR;
  cxxopts::Options opts = pipeline_options(src);
  try {
    const auto args = opts.parse(argc, argv);
    if (args.count("help")) {
      std::puts(opts.help().c_str());
      return 0;
    }
    Bench b;
    b.threads = std::max(1, args["threads"].as<int>());
    b.runs = std::max(1, args["runs"].as<int>());
    omp_set_num_threads(b.threads);
    const std::set<std::string> parts = parse_parts(args["only"].as<std::string>());
    b.every = args["every"].as<int>();
    if (b.every < 1) throw std::runtime_error("--every must be >= 1");
    b.model = choose_model(args, src);
    b.meta = nn::read_checkpoint_meta(b.model.path);
    const std::string scenario = args["scenario"].as<std::string>(), kpi_file = args["kpi"].as<std::string>();
    b.whole = [&] { return infer::SimPipeline::from_files(scenario, kpi_file, b.model.path); };
    const int frames = args["frames"].as<int>();
    b.n = args["objects"].as<int>();
    b.object_frames = args["object-frames"].as<int>();
    const sensor::KpiModel kpi = sensor::load_kpi_model(kpi_file);
    b.objects = [&] {
      const sensor::Scenario base = sensor::read_scenario(scenario);
      infer::SimOptions object_only;
      object_only.point_cloud = false;
      return infer::SimPipeline(bench::synthetic_scenario(b.n, b.object_frames / 10.0 + 1, base), kpi, nullptr,
                                object_only);
    };

    if (args.count("digest")) {
      auto p = b.whole();
      const int f = frames > 0 ? std::min(frames, p.frame_count()) : p.frame_count();
      std::printf("digest whole pipeline (%d frames): %016llx\n", f, static_cast<unsigned long long>(digest_run(p, f)));
      auto o = b.objects();
      std::printf("digest object-level model (%d objects, %d frames): %016llx\n", b.n, b.object_frames,
                  static_cast<unsigned long long>(digest_run(o, b.object_frames)));
      if (!b.model.temp.empty()) fs::remove(b.model.temp);
      return 0;
    }

    nlohmann::json j{{"threads", b.threads}, {"runs", b.runs}};
    std::vector<std::string> table;
    if (parts.count("whole") || parts.count("outputs")) {
      auto warm = b.whole();  // first-touch of buffers and weights, not measured
      infer::SimFrame f;
      for (int k = 0; k < 3; ++k) warm.run_frame(k, f);
      b.frames_used = frames > 0 ? std::min(frames, warm.frame_count()) : warm.frame_count();
    }
    if (parts.count("whole")) table.push_back(measure_whole(b, j));
    if (parts.count("objects")) table.push_back(measure_objects(b, j));
    if (parts.count("outputs")) table.push_back(measure_outputs(b, args.count("intensity-every-frame") > 0, j));

    double load[3] = {0, 0, 0};
    if (getloadavg(load, 3) < 0) load[0] = -1;
    // Wall-clock rates are what a rig sees; on a shared machine they include waiting for a core,
    // so the CPU-time bound is printed next to them (load average at the end of the run).
    std::printf("\n| measurement | frames/s (wall, median of %d) | frames/s bound from CPU time | target | met (wall) |\n"
                "|---|---:|---:|---:|---|\n", b.runs);
    for (const auto& row : table) std::printf("%s\n", row.c_str());
    std::printf("load average %.2f (1 min) on %ld online CPUs\n", load[0], sysconf(_SC_NPROCESSORS_ONLN));
    j["loadavg_end"] = load[0];
    if (args.count("json")) write_file_atomically(args["json"].as<std::string>(), j.dump(2) + "\n");
    if (!b.model.temp.empty()) fs::remove(b.model.temp);
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "error: %s\n", e.what());
    return 1;
  }
}
