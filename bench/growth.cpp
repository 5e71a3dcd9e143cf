// How cost grows with the size of the work: the object-level model against the number
// of objects, UNet inference against the number of columns, and training time per epoch against
// the number of scans. Each series is timed (median of --reps), its growth exponent fitted on a
// log-log scale (time ~ size^k by least squares) and compared with the order the algorithm should
// have; all three are drawn into one PNG (--png) and written as JSON (--json). Times are process
// CPU time (all threads), so that a shared machine's waiting does not count as cost.
//
// Expected orders: object model O(n) (every stage does constant work per object: the occlusion
// raster visits each box's own cells, association looks only at detections within a track's
// gate); inference O(columns) (convolutions over a grid of 64 x columns); an epoch O(scans) (one
// step per scan, plus validation of each scan's held-out cells).
#include <omp.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cxxopts.hpp>
#include <filesystem>
#include <functional>
#include <nlohmann/json.hpp>
#include <random>
#include <sstream>
#include <string>
#include <utility>
#include <vector>
#include <time.h>

#include "bench/synthetic_scenario.h"
#include "common/atomic_file.h"
#include "common/image.h"
#include "common/plot.h"
#include "data/dataset.h"
#include "infer/sim_outputs.h"
#include "infer/sim_pipeline.h"
#include "nn/checkpoint.h"
#include "nn/unet.h"
#include "pgm/polar_grid_map.h"
#include "sensor/kpi_model.h"
#include "train/trainer.h"

using namespace lidarsim;
namespace fs = std::filesystem;

namespace {

using Clock = std::chrono::steady_clock;

// Process CPU time (all threads): on a shared machine wall time mostly measures waiting for a
// core, while the CPU time a piece of work takes still grows with the work.
double cpu_seconds() {
  timespec ts{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return ts.tv_sec + 1e-9 * ts.tv_nsec;
}

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  const std::size_t n = v.size();
  return n == 0 ? 0 : n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

std::vector<int> parse_sizes(const std::string& text, const char* option) {
  std::vector<int> out;
  std::stringstream ss(text);
  std::string item;
  while (std::getline(ss, item, ',')) {
    char* end = nullptr;
    const long v = std::strtol(item.c_str(), &end, 10);
    if (item.empty() || *end != '\0' || v <= 0) throw std::runtime_error(std::string("--") + option + ": not a positive integer: \"" + item + "\"");
    out.push_back(static_cast<int>(v));
  }
  if (out.size() < 2) throw std::runtime_error(std::string("--") + option + ": needs at least two sizes");
  return out;
}

struct Series {
  Series(std::string n, std::string size, std::string time, std::string order, double k)
      : name(std::move(n)), size_label(std::move(size)), time_label(std::move(time)), expected(std::move(order)),
        expected_exponent(k) {}
  std::string name, size_label, time_label, expected;  // expected: "linear", ...
  double expected_exponent = 1;
  std::vector<double> sizes, seconds;
  double exponent = 0, intercept = 0;  // log10(seconds) = intercept + exponent log10(size)
  std::vector<std::string> notes;       // per point (e.g. the stage split)
};

void fit(Series& s) {
  const int n = static_cast<int>(s.sizes.size());
  double mx = 0, my = 0;
  for (int i = 0; i < n; ++i) {
    mx += std::log10(s.sizes[i]) / n;
    my += std::log10(s.seconds[i]) / n;
  }
  double sxy = 0, sxx = 0;
  for (int i = 0; i < n; ++i) {
    const double dx = std::log10(s.sizes[i]) - mx;
    sxy += dx * (std::log10(s.seconds[i]) - my);
    sxx += dx * dx;
  }
  s.exponent = sxy / sxx;
  s.intercept = my - s.exponent * mx;
}

// The verdict printed and stored: within 0.15 of the expected exponent counts as that order.
std::string verdict(const Series& s) {
  const double d = s.exponent - s.expected_exponent;
  if (std::abs(d) <= 0.15) return "as expected (" + s.expected + ")";
  return d > 0 ? "grows faster than " + s.expected : "grows slower than " + s.expected + " (fixed costs dominate small sizes)";
}

// 1. Object-level model: ms per frame against objects.
Series object_model(const std::vector<int>& counts, int frames, int reps, const sensor::Scenario& base,
                    const sensor::KpiModel& kpi) {
  Series s{"object-level model (sample, FoV, occlusion, tracking, KPI)", "objects", "CPU ms per frame", "linear", 1};
  for (int n : counts) {
    const sensor::Scenario sc = bench::synthetic_scenario(n, frames / 10.0 + 1, base);
    infer::SimOptions opt;
    opt.point_cloud = false;
    std::vector<double> runs;
    std::array<std::vector<double>, infer::kNumSimStages> stage;
    for (int r = 0; r < reps; ++r) {
      infer::SimPipeline p(sc, kpi, nullptr, opt);
      infer::SimFrame f;
      infer::SimStats st;
      const double c0 = cpu_seconds();
      for (int k = 0; k < frames; ++k) {
        p.run_frame(k, f);
        st.add(f);
      }
      runs.push_back((cpu_seconds() - c0) / frames);
      for (int i = 0; i < infer::kNumSimStages; ++i) stage[i].push_back(st.mean_ms(i));
    }
    s.sizes.push_back(n);
    s.seconds.push_back(median(runs));
    std::string note;
    char buf[64];
    for (auto st : {infer::SimStage::Sample, infer::SimStage::FieldOfView, infer::SimStage::Occlusion,
                    infer::SimStage::Tracking, infer::SimStage::Kpi}) {
      std::snprintf(buf, sizeof buf, "%s%s %.3f", note.empty() ? "" : ", ", infer::to_string(st),
                    median(stage[static_cast<int>(st)]));
      note += buf;
    }
    s.notes.push_back("wall ms per stage: " + note);
    std::fprintf(stderr, "growth: %d objects: %.4f ms/frame (%s ms)\n", n, 1e3 * s.seconds.back(), note.c_str());
  }
  return s;
}

// 2. Inference of the bundled model's architecture against columns (64 rows).
Series inference(const std::vector<int>& columns, int reps, const nn::UNetConfig& config) {
  Series s{"UNet inference, 64 rows, base " + std::to_string(config.base) + ", depth " + std::to_string(config.depth),
           "columns", "CPU s per scan", "linear", 1};
  nn::UNet model(config);
  model.init(1);
  for (int cols : columns) {
    nn::Tensor x(1, config.in_channels, 64, cols), y;
    std::mt19937 rng(3);
    std::uniform_real_distribution<float> u(0, 1);
    for (std::size_t i = 0; i < x.numel(); ++i) x.data()[i] = u(rng);
    model.predict(x, y);  // warm-up: buffers sized for this grid
    std::vector<double> t;
    for (int r = 0; r < reps; ++r) {
      const double c0 = cpu_seconds();
      model.predict(x, y);
      t.push_back(cpu_seconds() - c0);
    }
    s.sizes.push_back(cols);
    s.seconds.push_back(median(t));
    s.notes.push_back("");
    std::fprintf(stderr, "growth: %d columns: %.4f s\n", cols, s.seconds.back());
  }
  return s;
}

// A synthetic training set: `frames` scans of 64 x cols where intensity depends on class and
// range over a smooth scene (as tests/train's set, larger).
data::Dataset synthetic_set(int frames, int cols) {
  data::Dataset d;
  d.channels = {"range", "class", "material"};
  const auto layout = pgm::BeamLayout::uniform(64, 2.0, -24.8, cols);
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> jitter(-1.f, 1.f);
  for (int f = 0; f < frames; ++f) {
    pgm::PolarGridMap map(layout, {"range", "class", "material", "intensity", "mask"});
    const int ir = map.channel_index("range"), ic = map.channel_index("class"), im = map.channel_index("material"),
              ii = map.channel_index("intensity"), ik = map.channel_index("mask");
    for (int r = 0; r < map.rows(); ++r)
      for (int c = 0; c < map.cols(); ++c) {
        if ((r * 7 + c * 3 + f) % 5 == 0) continue;
        const float rg = 4.f + 0.8f * r + 8.f * std::sin(0.05f * c + f) + 0.2f * jitter(rng);
        const int cls = (c / 16) % 2 ? pgm::cls::road : pgm::cls::car;
        map.at(ir, r, c) = rg;
        map.at(ic, r, c) = static_cast<float>(cls);
        map.at(im, r, c) = static_cast<float>(pgm::default_material(cls));
        map.at(ii, r, c) = (cls == pgm::cls::car ? 0.6f : 0.2f) - rg / 200.f;
        map.at(ik, r, c) = 1.f;
      }
    d.append(map, "synthetic/" + std::to_string(f), "ring");
  }
  return d;
}

// 3. Training: seconds per epoch (median over the epochs after the first) against scans.
Series training(const std::vector<int>& scans, int cols, int epochs, int threads) {
  Series s{"training epoch, 64 x " + std::to_string(cols) + " scans, base 8, depth 3", "scans",
           "CPU s per epoch", "linear", 1};
  for (int n : scans) {
    const data::Dataset set = synthetic_set(n, cols);
    train::TrainConfig c;
    c.base = 8;
    c.depth = 3;
    c.epochs = epochs;
    c.batch = 1;
    c.threads = threads;
    c.out.clear();
    c.progress = false;
    c.split = "interleaved";  // this measures time, not generalisation; narrow scans hold no guard bands
    std::vector<double> t;
    double last = cpu_seconds();
    train::train_on(c, {&set}, {"synthetic"}, nullptr, [&](const train::EpochReport&) {
      const double now = cpu_seconds();
      t.push_back(now - last);
      last = now;
    });
    if (t.size() > 1) t.erase(t.begin());  // the first epoch also sizes every buffer
    s.sizes.push_back(n);
    s.seconds.push_back(median(t));
    s.notes.push_back("");
    std::fprintf(stderr, "growth: %d scans: %.3f s/epoch\n", n, s.seconds.back());
  }
  return s;
}

// Log-log chart of one series: measured points, the fitted line, and the expected slope through
// the first point (dashed look: short segments).
Image chart(const Series& s) {
  double x0 = 1e300, x1 = -1e300, y0 = 1e300, y1 = -1e300;
  for (std::size_t i = 0; i < s.sizes.size(); ++i) {
    x0 = std::min(x0, std::log10(s.sizes[i]));
    x1 = std::max(x1, std::log10(s.sizes[i]));
    y0 = std::min(y0, std::log10(s.seconds[i]));
    y1 = std::max(y1, std::log10(s.seconds[i]));
  }
  const double ey = s.expected_exponent * (x1 - x0) + std::log10(s.seconds.front());
  y1 = std::max(y1, ey);
  y0 = std::min(y0, ey);
  ChartSpec spec;
  spec.width = 960;
  spec.height = 420;
  char title[256];
  std::snprintf(title, sizeof title, "%s: exponent %.2f", s.name.c_str(), s.exponent);
  spec.title = title;
  spec.x_label = s.size_label + " (log scale)";
  spec.y_label = s.time_label + " (log scale)";
  spec.x_lo = x0 - 0.05 * (x1 - x0);
  spec.x_hi = x1 + 0.05 * (x1 - x0);
  spec.y_lo = std::floor(y0 * 2) / 2 - 0.1;
  spec.y_hi = std::ceil(y1 * 2) / 2 + 0.1;
  for (double v : s.sizes) spec.x_ticks.push_back({std::log10(v), std::to_string(static_cast<long>(v))});
  // y ticks at 1, 2, 5 x 10^k within the range.
  for (int k = static_cast<int>(std::floor(spec.y_lo)); k <= static_cast<int>(std::ceil(spec.y_hi)); ++k)
    for (double m : {1.0, 2.0, 5.0}) {
      const double y = k + std::log10(m);
      if (y < spec.y_lo || y > spec.y_hi) continue;
      const double v = m * std::pow(10.0, k);
      char buf[32];
      std::snprintf(buf, sizeof buf, "%g", v);
      spec.y_ticks.push_back({y, buf});
    }
  Chart c(spec);
  const Rgb measured{31, 119, 180}, fitted{214, 39, 40}, expected{120, 120, 120};
  // Expected order through the first point, drawn in dashes.
  const double ex0 = std::log10(s.sizes.front()), ey0 = std::log10(s.seconds.front());
  const int dashes = 24;
  for (int i = 0; i < dashes; i += 2) {
    const double a = ex0 + (x1 - ex0) * i / dashes, b = ex0 + (x1 - ex0) * (i + 1) / dashes;
    c.line(a, ey0 + s.expected_exponent * (a - ex0), b, ey0 + s.expected_exponent * (b - ex0), expected, 2);
  }
  c.line(x0, s.intercept + s.exponent * x0, x1, s.intercept + s.exponent * x1, fitted, 2);
  for (std::size_t i = 0; i < s.sizes.size(); ++i) c.marker(std::log10(s.sizes[i]), std::log10(s.seconds[i]), measured, 5);
  char fit_label[64];
  std::snprintf(fit_label, sizeof fit_label, "fit: time ~ size^%.2f", s.exponent);
  c.legend({{"measured (median)", measured, Mark::marker},
            {fit_label, fitted, Mark::line},
            {"expected: " + s.expected, expected, Mark::line}});
  return c.image();
}

// Fits each series' exponent, prints it with its verdict, and returns the JSON rows and a chart
// per series.
nlohmann::json report_series(std::vector<Series>& series, std::vector<Image>& charts) {
  nlohmann::json out = nlohmann::json::array();
  for (Series& s : series) {
    fit(s);
    std::printf("%s\n", s.name.c_str());
    for (std::size_t i = 0; i < s.sizes.size(); ++i)
      std::printf("  %6.0f %s: %.5g %s%s%s\n", s.sizes[i], s.size_label.c_str(),
                  s.time_label.find("ms") != std::string::npos ? 1e3 * s.seconds[i] : s.seconds[i], s.time_label.c_str(),
                  s.notes[i].empty() ? "" : "; ", s.notes[i].c_str());
    std::printf("  fitted exponent %.2f, expected %.0f (%s): %s\n", s.exponent, s.expected_exponent, s.expected.c_str(),
                verdict(s).c_str());
    out.push_back({{"name", s.name}, {"size", s.size_label}, {"sizes", s.sizes}, {"seconds", s.seconds},
                   {"notes", s.notes}, {"exponent", s.exponent}, {"expected", s.expected},
                   {"expected_exponent", s.expected_exponent}, {"verdict", verdict(s)}});
    // Charts in the label's unit (ms for the object model).
    Series shown = s;
    if (s.time_label.find("ms") != std::string::npos)
      for (double& v : shown.seconds) v *= 1e3;
    fit(shown);
    charts.push_back(chart(shown));
  }
  return out;
}

}  // namespace

int main(int argc, char** argv) {
  const fs::path src = LIDARSIM_SOURCE_DIR;
  cxxopts::Options opts("bench_growth", "how cost grows: object model vs objects, inference vs columns, epoch vs scans");
  // clang-format off
  opts.add_options()
    ("objects", "object counts", cxxopts::value<std::string>()->default_value("10,30,100,300,1000"))
    ("object-frames", "frames per object-model run", cxxopts::value<int>()->default_value("300"))
    ("columns", "inference columns", cxxopts::value<std::string>()->default_value("512,1024,2048,4096"))
    ("scans", "training scans (1x, 4x, 16x)", cxxopts::value<std::string>()->default_value("2,8,32"))
    ("train-columns", "columns of the training scans", cxxopts::value<int>()->default_value("256"))
    ("epochs", "epochs per training run (the first is not timed)", cxxopts::value<int>()->default_value("3"))
    ("reps", "repetitions per point (median)", cxxopts::value<int>()->default_value("3"))
    ("threads", "OpenMP threads", cxxopts::value<int>()->default_value("2"))
    ("only", "run only these series: objects, inference, training (comma-separated)", cxxopts::value<std::string>()->default_value("objects,inference,training"))
    ("scenario", "scenario whose sensor the object model uses", cxxopts::value<std::string>()->default_value((src / "data/scenarios/demo_urban.json").string()))
    ("kpi", "KPI model", cxxopts::value<std::string>()->default_value((src / "data/models/kpi_pointrcnn.json").string()))
    ("png", "write the chart here", cxxopts::value<std::string>())
    ("json", "write the results here", cxxopts::value<std::string>())
    ("h,help", "help");
  // clang-format on
  try {
    const auto args = opts.parse(argc, argv);
    if (args.count("help")) {
      std::puts(opts.help().c_str());
      return 0;
    }
    const int threads = std::max(1, args["threads"].as<int>()), reps = std::max(1, args["reps"].as<int>());
    omp_set_num_threads(threads);
    const std::string only = "," + args["only"].as<std::string>() + ",";
    auto wanted = [&](const char* name) { return only.find("," + std::string(name) + ",") != std::string::npos; };

    std::vector<Series> series;
    if (wanted("objects")) {
      const sensor::Scenario base = sensor::read_scenario(args["scenario"].as<std::string>());
      const sensor::KpiModel kpi = sensor::load_kpi_model(args["kpi"].as<std::string>());
      series.push_back(object_model(parse_sizes(args["objects"].as<std::string>(), "objects"),
                                    std::max(10, args["object-frames"].as<int>()), reps, base, kpi));
    }
    if (wanted("inference")) {
      nn::UNetConfig config{4, 1, 8, 3};  // the bundled model's shape when it is not there to read
      const fs::path bundled = src / "data/models/intensity_unet.h5";
      if (fs::exists(bundled)) config = nn::read_checkpoint_meta(bundled).unet;
      series.push_back(inference(parse_sizes(args["columns"].as<std::string>(), "columns"), reps, config));
    }
    if (wanted("training"))
      series.push_back(training(parse_sizes(args["scans"].as<std::string>(), "scans"), args["train-columns"].as<int>(),
                                std::max(2, args["epochs"].as<int>()), threads));

    double load[3] = {0, 0, 0};
    if (getloadavg(load, 3) < 0) load[0] = -1;
    std::vector<Image> charts;
    const nlohmann::json out = report_series(series, charts);
    std::printf("%d thread(s), load average %.2f at the end\n", threads, load[0]);
    if (args.count("png") && !charts.empty()) write_png(args["png"].as<std::string>(), stack_vertically(charts, 8));
    if (args.count("json"))
      write_file_atomically(args["json"].as<std::string>(),
                            nlohmann::json{{"threads", threads}, {"reps", reps}, {"loadavg_end", load[0]}, {"series", out}}.dump(2) + "\n");
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "error: %s\n", e.what());
    return 1;
  }
}
