// Per-frame latency of the OSI interface against the pipeline's own time (issues 14 and 29): a
// co-simulation sends one osi3.SensorView (host + --objects moving objects, lane boundaries) and
// waits for the whole osi3.SensorData, frame after frame, through
//   - the stream: `lidar-infer osi --in - --out -` as a child process on two pipes (SensorView
//     written -> SensorData read back), and
//   - the FMU: lidarsim_osi.fmu in this process as an importer drives it (set the pointer
//     integers, fmi2DoStep, get them);
// and, as the peer, the same frames through OsiRunner in this process, whose model stages
// (SimPipeline, outputs excluded: what bench_pipeline times) are "the pipeline's own time". The
// three run frame k one after the other (each frame another one first) before frame k + 1, so
// load on the machine falls on all of them alike. Also timed per frame, in process: decoding the
// SensorView (osi::decode_sensor_view) and libprotobuf's parse it replaces, SensorView -> scene,
// encoding the SensorData (osi::encode_sensor_data), and the protobuf path it replaces (building
// the message, SerializeToString); and a client's libprotobuf parse of the SensorData it got. All
// four must give the same bytes (counted). Median and p99 over --frames after --warmup frames; the
// CPU and the load average are printed.
#include <omp.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <cxxopts.hpp>
#include <filesystem>
#include <fstream>
#include <functional>
#include <memory>
#include <random>
#include <string>
#include <string_view>
#include <vector>

#include "bench/osi_bench_scene.h"
#include "bench/osi_fmu_host.h"
#include "common/error.h"
#include "infer/osi_runner.h"
#include "osi/osi3_subset.pb.h"
#include "osi/sensor_data.h"
#include "osi/sensor_view.h"
#include "osi/sensor_view_decoder.h"

using namespace lidarsim;
namespace fs = std::filesystem;

namespace {

struct Stats {
  double median = 0, p99 = 0;
};

Stats stats(std::vector<double> v) {
  if (v.empty()) return {};
  std::sort(v.begin(), v.end());
  const std::size_t rank99 = (v.size() * 99 + 99) / 100;  // nearest rank: ceil(0.99 n)
  return {v[v.size() / 2], v[std::max<std::size_t>(rank99, 1) - 1]};
}

std::string cpu_name() {
  std::ifstream in("/proc/cpuinfo");
  std::string line;
  while (std::getline(in, line))
    if (line.rfind("model name", 0) == 0) return line.substr(line.find(':') + 2);
  return "unknown CPU";
}

// Host driving at 10 m/s along x; objects on both sides and ahead, 80 % cars at 8-14 m/s along
// the road, 20 % pedestrians crossing at 1.4 m/s; two solid lane boundaries.
std::vector<std::string> make_frames(int frames, int objects) {
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> ux(-30, 60), uy(-20, 20), uv(8, 14);
  struct O {
    double x, y, vx, vy;
    bool ped;
  };
  std::vector<O> os;
  for (int i = 0; i < objects; ++i) {
    const bool ped = i % 5 == 4;
    double x = ux(rng), y = uy(rng);
    if (std::abs(y) < 3 && std::abs(x) < 8) y += 6;  // not on top of the host
    os.push_back({x, y, ped ? 10.0 : uv(rng), ped ? (y > 0 ? -1.4 : 1.4) : 0.0, ped});
  }
  std::vector<std::string> out;
  for (int k = 0; k < frames; ++k) {
    const double t = 0.1 * k;
    osi3::SensorView v;
    osi::set_timestamp(t, *v.mutable_timestamp());
    v.mutable_sensor_id()->set_value(1);
    v.mutable_host_vehicle_id()->set_value(1000);
    v.mutable_mounting_position()->mutable_position()->set_x(1.4);
    v.mutable_mounting_position()->mutable_position()->set_z(1.43);
    auto& gt = *v.mutable_global_ground_truth();
    auto add = [&](std::uint64_t id, bool ped, double x, double y, double vx, double vy) {
      return lidarsim::bench::add_bench_object(gt, id, ped, x, y, vx, vy);
    };
    auto* host = add(1000, false, 10 * t + 1.4, 0, 10, 0);
    host->mutable_vehicle_attributes()->mutable_bbcenter_to_rear()->set_x(-1.4);
    host->mutable_vehicle_attributes()->mutable_bbcenter_to_rear()->set_z(-0.45);
    for (std::size_t i = 0; i < os.size(); ++i)
      add(i + 1, os[i].ped, os[i].x + os[i].vx * t, os[i].y + os[i].vy * t, os[i].vx, os[i].vy);
    for (int side : {-1, 1}) {
      auto* l = gt.add_lane_boundary();
      l->mutable_id()->set_value(side < 0 ? 2001 : 2002);
      l->mutable_classification()->set_type(osi3::LaneBoundary::Classification::TYPE_SOLID_LINE);
      for (double x = -50; x <= 200; x += 10) {
        auto* p = l->add_boundary_line()->mutable_position();
        p->set_x(x);
        p->set_y(side * 1.75);
      }
    }
    out.push_back(v.SerializeAsString());
  }
  return out;
}

void write_all(int fd, const char* p, std::size_t n) {
  while (n > 0) {
    const ssize_t w = ::write(fd, p, n);
    if (w <= 0) throw Error("bench: write to lidar-infer failed");
    p += w;
    n -= static_cast<std::size_t>(w);
  }
}

void read_all(int fd, char* p, std::size_t n) {
  while (n > 0) {
    const ssize_t r = ::read(fd, p, n);
    if (r <= 0) throw Error("bench: lidar-infer closed its output early");
    p += r;
    n -= static_cast<std::size_t>(r);
  }
}

// lidar-infer osi --in - --out - as a child process; round_trip() sends one frame and reads its reply.
class Stream {
 public:
  Stream(const fs::path& exe, int threads, bool objects_only) {
    int to_child[2], from_child[2];
    if (pipe(to_child) || pipe(from_child)) throw Error("bench: pipe failed");
    pid_ = fork();
    if (pid_ == 0) {
      dup2(to_child[0], 0);
      dup2(from_child[1], 1);
      close(to_child[1]);
      close(from_child[0]);
      const std::string t = std::to_string(threads);
      std::vector<const char*> argv{exe.c_str(), "osi", "--in", "-", "--out", "-", "--threads", t.c_str(), "--quiet"};
      if (objects_only) argv.push_back("--no-point-cloud");
      argv.push_back(nullptr);
      execv(exe.c_str(), const_cast<char* const*>(argv.data()));
      std::perror("exec lidar-infer");
      _exit(127);
    }
    close(to_child[0]);
    close(from_child[1]);
    to_ = to_child[1];
    from_ = from_child[0];
  }
  // The length-prefixed SensorView out, the whole length-prefixed SensorData back into `reply`.
  void round_trip(const std::string& view, std::string& reply) {
    const auto n = static_cast<std::uint32_t>(view.size());
    const char header[4] = {static_cast<char>(n), static_cast<char>(n >> 8), static_cast<char>(n >> 16),
                            static_cast<char>(n >> 24)};
    write_all(to_, header, 4);
    write_all(to_, view.data(), view.size());
    unsigned char len[4];
    read_all(from_, reinterpret_cast<char*>(len), 4);
    reply.resize(len[0] | len[1] << 8 | len[2] << 16 | static_cast<std::uint32_t>(len[3]) << 24);
    read_all(from_, reply.data(), reply.size());
  }
  void finish() {
    close(to_);
    int status = 0;
    waitpid(pid_, &status, 0);
    close(from_);
    if (!WIFEXITED(status) || WEXITSTATUS(status) != 0) throw Error("bench: lidar-infer osi failed");
  }

 private:
  pid_t pid_ = -1;
  int to_ = -1, from_ = -1;
};

enum Phase {
  kPipeline, kStream, kFmu, kDecodeView, kParseView, kScene, kEncode, kBuild, kSerialize, kClientParse, kPhases
};
constexpr const char* kPhaseNames[kPhases] = {"the pipeline's own time (model stages, in process)",
                                              "stream round trip (SensorView written -> SensorData read)",
                                              "FMU round trip (set, fmi2DoStep, get)",
                                              "in process: decode the SensorView (osi/sensor_view_decoder.h)",
                                              "in process, replaced: parse the SensorView (libprotobuf)",
                                              "in process: SensorView -> scene",
                                              "in process: encode the SensorData (osi/sensor_data_encoder.cpp)",
                                              "in process, replaced: build the SensorData message",
                                              "in process, replaced: SerializeToString",
                                              "client: parse the SensorData (libprotobuf)"};

struct Run {
  std::vector<double> t[kPhases];                                        // ms per measured frame
  std::size_t objects = 0, points = 0, bytes = 0;                        // summed over measured frames
  std::size_t differ_protobuf = 0, differ_stream = 0, differ_fmu = 0;  // frames
};

// Every frame through the stream, the FMU (when given) and the runner, in turn.
Run run_frames(const std::vector<std::string>& msgs, int warmup, infer::OsiRunner& runner, Stream& stream,
               bench::FmuHost* fmu) {
  using clock = std::chrono::steady_clock;
  auto since = [](clock::time_point a) { return std::chrono::duration<double, std::milli>(clock::now() - a).count(); };
  Run run;
  auto& t = run.t;
  osi3::SensorView view;
  osi::msg::SensorView decoded;
  osi3::SensorData message, client;
  std::string ours, theirs, reply;
  for (std::size_t k = 0; k < msgs.size(); ++k) {
    const bool measured = static_cast<int>(k) >= warmup;
    auto keep = [&](Phase p, double ms) {
      if (measured) t[p].push_back(ms);
    };
    // The three in turn, the first a different one each frame: none always runs on caches or a
    // machine the others left behind.
    const auto run_stream = [&] {
      auto t0 = clock::now();
      stream.round_trip(msgs[k], reply);
      keep(kStream, since(t0));
      t0 = clock::now();
      if (!client.ParseFromString(reply)) throw Error("bench: frame " + std::to_string(k) + ": the reply does not parse");
      keep(kClientParse, since(t0));
    };
    std::string_view from_fmu;
    const auto run_fmu = [&] {
      if (!fmu) return;
      const auto t0 = clock::now();
      from_fmu = fmu->step(msgs[k], 0.1 * static_cast<double>(k), 0.1);
      keep(kFmu, since(t0));
    };
    const auto run_in_process = [&] {
      auto t0 = clock::now();
      osi::decode_sensor_view(msgs[k], "bench", static_cast<long>(k), decoded);
      keep(kDecodeView, since(t0));
      t0 = clock::now();
      view.ParseFromString(msgs[k]);
      keep(kParseView, since(t0));
      runner.step(decoded, static_cast<long>(k), "bench", ours);
      keep(kPipeline, runner.last_times().model_ms);
      keep(kScene, runner.last_times().scene_ms);
      keep(kEncode, runner.last_times().output_ms);
      t0 = clock::now();
      runner.last_sensor_data(message);
      keep(kBuild, since(t0));
      t0 = clock::now();
      message.SerializeToString(&theirs);
      keep(kSerialize, since(t0));
    };
    const std::function<void()> order[3] = {run_stream, run_fmu, run_in_process};
    for (std::size_t r = 0; r < 3; ++r) order[(k + r) % 3]();
    run.differ_protobuf += ours != theirs;
    run.differ_stream += reply != ours;
    run.differ_fmu += fmu && from_fmu != ours;
    if (measured) {
      run.objects += runner.reported_objects();
      run.points += runner.reported_points();
      run.bytes += ours.size();
    }
  }
  return run;
}

void report(const Run& run, int frames) {
  double load[3] = {0, 0, 0};
  if (std::FILE* f = std::fopen("/proc/loadavg", "r")) {
    if (std::fscanf(f, "%lf %lf %lf", &load[0], &load[1], &load[2]) != 3) load[0] = -1;
    std::fclose(f);
  }
  Stats s[kPhases];
  for (int p = 0; p < kPhases; ++p) s[p] = stats(run.t[p]);
  std::printf("(%.0f reported objects, %.0f lidar detections, %.2f MB of SensorData per frame)\n"
              "%s, %ld cores, load average %.2f %.2f %.2f\n\n",
              double(run.objects) / frames, double(run.points) / frames, double(run.bytes) / frames / 1e6,
              cpu_name().c_str(), sysconf(_SC_NPROCESSORS_ONLN), load[0], load[1], load[2]);
  std::printf("| per frame (ms) | median | p99 |\n|---|---:|---:|\n");
  for (int p = 0; p < kPhases; ++p)
    if (!run.t[p].empty()) std::printf("| %s | %.2f | %.2f |\n", kPhaseNames[p], s[p].median, s[p].p99);
  std::printf("\nstream / pipeline: median %.2f, p99 %.2f (targets 1.2 and 1.5)\n", s[kStream].median / s[kPipeline].median,
              s[kStream].p99 / s[kPipeline].p99);
  const bool fmu = !run.t[kFmu].empty();
  if (fmu)
    std::printf("FMU / pipeline:    median %.2f, p99 %.2f\n", s[kFmu].median / s[kPipeline].median,
                s[kFmu].p99 / s[kPipeline].p99);
  std::printf("frames whose bytes differ from the in-process encoder's: protobuf path %zu, stream %zu, FMU %s\n",
              run.differ_protobuf, run.differ_stream, fmu ? std::to_string(run.differ_fmu).c_str() : "-");
}

}  // namespace

int main(int argc, char** argv) {
  cxxopts::Options options("bench_osi_stream",
                           "Per-frame round trip of the OSI stream and FMU against the pipeline's own time");
  // clang-format off
  options.add_options()
    ("frames", "measured frames", cxxopts::value<int>()->default_value("100"))
    ("warmup", "frames before measuring (tracks confirm, buffers grow)", cxxopts::value<int>()->default_value("5"))
    ("objects", "moving objects besides the host", cxxopts::value<int>()->default_value("100"))
    ("threads", "OpenMP threads (every run)", cxxopts::value<int>()->default_value("2"))
    ("no-point-cloud", "object-level model only (every run)")
    ("exe", "lidar-infer (default: the one of this build)", cxxopts::value<std::string>()->default_value(""))
    ("fmu", "the FMU (default: the one of this build); 'none' skips it, as --no-point-cloud does", cxxopts::value<std::string>()->default_value(""))
    ("h,help", "help");
  // clang-format on
  const auto args = options.parse(argc, argv);
  if (args.count("help")) {
    std::printf("%s\n", options.help().c_str());
    return 0;
  }
  try {
    const int frames = args["frames"].as<int>(), warmup = args["warmup"].as<int>();
    const int threads = args["threads"].as<int>();
    if (frames < 1 || warmup < 0 || threads < 1) throw Error("--frames and --threads must be >= 1, --warmup >= 0");
    const std::string src = LIDARSIM_SOURCE_DIR;
    const fs::path build = fs::canonical("/proc/self/exe").parent_path().parent_path();
    fs::path exe = args["exe"].as<std::string>(), fmu_path = args["fmu"].as<std::string>();
    if (exe.empty()) exe = build / "infer" / "lidar-infer";
    if (fmu_path.empty()) fmu_path = build / "lidarsim_osi.fmu";
    const bool objects_only = args.count("no-point-cloud") > 0;
    const bool with_fmu = fmu_path != "none" && !objects_only;  // the FMU always runs the whole model
    const auto msgs = make_frames(warmup + frames, args["objects"].as<int>());
    omp_set_num_threads(threads);
    infer::SimOptions sim;
    if (objects_only) sim.point_cloud = sim.intensity = false;
    auto runner = infer::OsiRunner::from_files(src + "/data/scenarios/demo_urban.json",
                                               src + "/data/models/kpi_pointrcnn.json",
                                               src + "/data/models/intensity_unet.h5", sim);
    Stream stream(exe, threads, objects_only);
    std::unique_ptr<bench::FmuHost> fmu;
    if (with_fmu) fmu = std::make_unique<bench::FmuHost>(fmu_path);

    const Run run = run_frames(msgs, warmup, runner, stream, fmu.get());
    stream.finish();

    std::printf("bench_osi_stream%s: %d objects, %d threads, %d frames after %d warm-up\n",
                objects_only ? " --no-point-cloud" : "", args["objects"].as<int>(), threads, frames, warmup);
    report(run, frames);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "error: %s\n", e.what());
    return 1;
  }
  return 0;
}
