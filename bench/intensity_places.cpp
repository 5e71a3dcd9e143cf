// Intensity held out by place: every place held out whole in turn, trained on
// the others that share its grid and intensity scale (data/place_split.h). Driven by
// scripts/intensity_places.sh, which imports the places and trains the UNets with lidar-train:
//   bench_intensity_places --data seq00=a.h5,seq08=b.h5,... --plan
//       one line per held-out place: "fold|held|train1,train2|excluded; ..." (the
//       script trains on exactly these)
//   bench_intensity_places --data ... --models DIR --variants rcm,range --out PREFIX
//       scores DIR/<held>.<variant>.h5 on every cell of the held-out place beside the lookups of
//       data/baselines.h (and the loop's per-beam lookup, qualify/intensity/intensity.h) fitted on the same
//       training places, with the histogram intersection and its real-vs-real ceiling of
//       `lidar-qualify intensity` (qualify/similarity.h; ceiling: the held-out place's scans in
//       two alternating halves); writes PREFIX.json and PREFIX.md atomically.
// Before scoring, the training datasets the checkpoint itself names (its train_config) are opened
// and checked to hold no frame of the held-out place.
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cxxopts.hpp>
#include <filesystem>
#include <map>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>
#include <vector>

#include "common/atomic_file.h"
#include "common/error.h"
#include "data/baselines.h"
#include "data/dataset.h"
#include "data/place_split.h"
#include "infer/intensity_model.h"
#include "nn/checkpoint.h"
#include "qualify/intensity/intensity.h"
#include "qualify/similarity.h"

using namespace lidarsim;
namespace fs = std::filesystem;

namespace {

std::vector<std::string> split_list(const std::string& s) {
  std::vector<std::string> out;
  std::stringstream in(s);
  for (std::string item; std::getline(in, item, ',');)
    if (!item.empty()) out.push_back(item);
  return out;
}

std::string join(const std::vector<std::string>& v, const std::string& sep) {
  std::string s;
  for (const auto& x : v) s += (s.empty() ? "" : sep) + x;
  return s;
}

// The training files a checkpoint names (--data and --train-also of its lidar-train run).
std::vector<std::string> checkpoint_training_files(const fs::path& checkpoint) {
  const auto meta = nn::read_checkpoint_meta(checkpoint);
  const auto it = meta.attributes.find("train_config");
  if (it == meta.attributes.end()) throw Error(checkpoint.string() + ": /config: no train_config attribute");
  const auto j = nlohmann::json::parse(it->second);
  std::vector<std::string> files = j.at("data").get<std::vector<std::string>>();
  if (j.contains("train_also"))
    for (const auto& f : j["train_also"]) files.push_back(f.get<std::string>());
  return files;
}

// Lookup cells (qualify::IntensityCells, the fields its lookups read): the training places' cells
// fit, the held-out place's are scored. use_class false: every class reads as 0.
void add_cells(qualify::IntensityCells& c, const data::Dataset& d, bool held, bool use_class) {
  const int ci = d.channel_index("class"), ri = d.channel_index("range");
  const int H = d.rows(), W = d.cols();
  if (c.feature.empty()) c.feature.resize(1);
  for (int n = 0; n < d.size(); ++n) {
    const float* cls = d.pgm.channel(n, ci);
    const float* rng = d.pgm.channel(n, ri);
    const float* mask = d.mask.image(n);
    const float* y = d.target.image(n);
    for (int i = 0; i < H * W; ++i) {
      if (mask[i] <= 0) continue;
      c.measured.push_back(y[i]);
      c.frame.push_back(n);
      c.cls.push_back(use_class ? static_cast<int>(cls[i]) : 0);
      c.row.push_back(i / W);
      c.held_out.push_back(held);
      c.feature[0].push_back(rng[i]);
      c.cell.push_back(static_cast<long>(n) * H * W + i);
    }
  }
}

struct Scored {
  double mae = 0;
  double intersection = 0;
};

Scored score(const std::vector<double>& pred, const std::vector<double>& meas) {
  double abs = 0;
  for (std::size_t i = 0; i < pred.size(); ++i) abs += std::abs(pred[i] - meas[i]);
  return {pred.empty() ? 0 : abs / pred.size(), qualify::histogram_intersection(pred, meas)};
}

std::string fmt(double v, int digits = 4) {
  char b[32];
  std::snprintf(b, sizeof b, "%.*f", digits, v);
  return b;
}

// The held-out place's measured intensity (every returning cell) and its real-vs-real ceiling, as
// in lidar-qualify intensity: the place's scans alternate between two halves.
struct HeldOutPlace {
  std::vector<double> measured;
  double ceiling = -1;
};

HeldOutPlace measured_place(const data::Dataset& held) {
  HeldOutPlace h;
  std::vector<std::vector<double>> by_scan(held.size());
  for (int n = 0; n < held.size(); ++n) {
    const float* m = held.mask.image(n);
    const float* y = held.target.image(n);
    for (int i = 0; i < held.rows() * held.cols(); ++i)
      if (m[i] > 0) by_scan[n].push_back(y[i]), h.measured.push_back(y[i]);
  }
  h.ceiling = qualify::real_vs_real_ceiling(by_scan);
  return h;
}

struct Lookups {
  nlohmann::json mae = nlohmann::json::object();  // name -> held-out MAE
  std::string best_name;
  double best = 1e30;
  double beam_intersection = 0;  // class x range + beam lookup's histogram intersection
};

// Every lookup, with the class and without it (seq08 has none; the KITTI object frames label only
// boxes), fitted on the training places and scored on the held-out one; the best of all.
Lookups score_lookups(const std::vector<data::Dataset>& train, const data::Dataset& held,
                      const std::vector<double>& measured) {
  std::vector<const data::Dataset*> train_ptr;
  for (const auto& d : train) train_ptr.push_back(&d);
  Lookups l;
  for (const bool use_class : {true, false}) {
    const std::string suffix = use_class ? "" : " (no class)";
    for (const auto& b : data::evaluate_baselines_across(train_ptr, held, use_class))
      if (use_class)
        l.mae[b.name] = b.validation.mae;
      else if (b.name == "class_x_range" || b.name == "class_x_row")  // "range (no class)", "row (no class)"
        l.mae[b.name.substr(8) + suffix] = b.validation.mae;
    qualify::IntensityCells cells;
    for (const auto& d : train) add_cells(cells, d, false, use_class);
    add_cells(cells, held, true, use_class);
    const auto beam = qualify::lookup_beam_prediction(cells, held.rows());
    std::vector<double> beam_held;
    for (std::size_t i = 0; i < cells.size(); ++i)
      if (cells.held_out[i]) beam_held.push_back(beam[i]);
    const Scored sb = score(beam_held, measured);
    l.mae[use_class ? "class_x_range_beam" : "range_beam" + suffix] = sb.mae;
    if (use_class) l.beam_intersection = sb.intersection;
  }
  for (const auto& [name, mae] : l.mae.items())
    if (mae.get<double>() < l.best) l.best = mae.get<double>(), l.best_name = name;
  return l;
}

// The checkpoint's own record of what trained it, checked to hold no frame of the held-out place.
std::vector<std::string> checked_training_names(const fs::path& ck, const data::PlacedSet& held) {
  std::vector<data::PlacedSet> actual;
  std::vector<std::string> names;
  for (const auto& file : checkpoint_training_files(ck)) {
    actual.push_back(data::read_placed_set(file, file));
    names.push_back(fs::path(file).filename().string());
  }
  data::check_no_place_leak(held, actual);
  return names;
}

// The model's output (the mean, or after sample_from_spread a draw keyed by frame and cell).
std::vector<double> predict_returning_cells(infer::IntensityModel& model, const data::Dataset& held) {
  std::vector<double> unet;
  std::vector<float> out;
  for (int n = 0; n < held.size(); ++n) {
    model.predict(held.frame_pgm(n), out, static_cast<std::uint64_t>(n));
    const float* m = held.mask.image(n);
    for (int i = 0; i < held.rows() * held.cols(); ++i)
      if (m[i] > 0) unet.push_back(out[i]);
  }
  return unet;
}

// A checkpoint with a spread head, drawn once per seed (infer/intensity_sampling.h: its residual
// table and grid when it has them, fitted by lidar-train --early-stop on the training places' inner
// region): MAE and intersection of each draw. Empty without a spread head.
nlohmann::json score_draws(infer::IntensityModel& model, const data::Dataset& held, const HeldOutPlace& place,
                           const std::vector<std::uint64_t>& seeds, std::string& md) {
  nlohmann::json draws = nlohmann::json::array();
  if (!model.spread()) return draws;
  for (const std::uint64_t seed : seeds) {
    model.sample_from_spread({seed, 0.f, 1.f, false}, "bench_intensity_places");
    const Scored sd = score(predict_returning_cells(model, held), place.measured);
    draws.push_back({{"seed", seed}, {"mae", sd.mae}, {"intersection", sd.intersection}});
    md += (md.empty() ? "" : ", ") + fmt(sd.intersection, 3);
  }
  return draws;
}

struct Report {
  nlohmann::json rows = nlohmann::json::array();
  std::string md =
      "| held out | trained on | variant | cells | UNet MAE | best lookup MAE (which) | global mean MAE | "
      "UNet hist. int. | class x range + beam hist. int. | ceiling | UNet / ceiling | sampled hist. int. (seeds) | "
      "sampled / ceiling |\n"
      "|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n";
};

// One checkpoint variant of one fold, scored on every returning cell of the held-out place.
void score_variant(const data::PlaceFold& f, const data::PlacedSet& held, const data::Dataset& held_ds,
                   const HeldOutPlace& place, const Lookups& lookups, const fs::path& models,
                   const std::string& variant, const std::vector<std::uint64_t>& seeds, Report& report) {
  const fs::path ck = models / (f.held_out + "." + variant + ".h5");
  if (!fs::exists(ck)) throw Error(ck.string() + ": missing (run scripts/intensity_places.sh)");
  const std::vector<std::string> trained_on = checked_training_names(ck, held);
  std::fprintf(stderr, "intensity_places: %s held out, %s: UNet on %d frames...\n", f.held_out.c_str(),
               variant.c_str(), held_ds.size());
  infer::IntensityModel model = infer::IntensityModel::load(ck);
  const Scored su = score(predict_returning_cells(model, held_ds), place.measured);
  const double ceiling = place.ceiling, global = lookups.mae.at("global_mean").get<double>();
  const auto attrs = nn::read_checkpoint_meta(ck).attributes;
  const auto calibration = attrs.find("spread_calibration");  // where its table was fitted
  std::string drawn_md;
  const nlohmann::json draws = score_draws(model, held_ds, place, seeds, drawn_md);
  double drawn_mean = 0;
  for (const auto& d : draws) drawn_mean += d["intersection"].get<double>() / static_cast<double>(draws.size());
  report.rows.push_back({{"held_out", f.held_out},
                         {"training", f.training},
                         {"excluded", f.excluded},
                         {"checkpoint_trained_on", trained_on},
                         {"variant", variant},
                         {"channels", model.encoder().channels},
                         {"cells", static_cast<long>(place.measured.size())},
                         {"frames", held_ds.size()},
                         {"unet_mae", su.mae},
                         {"lookup_mae", lookups.mae},
                         {"best_lookup", lookups.best_name},
                         {"best_lookup_mae", lookups.best},
                         {"unet_intersection", su.intersection},
                         {"lookup_beam_intersection", lookups.beam_intersection},
                         {"sampled", draws},
                         {"spread_calibration", calibration == attrs.end() ? nlohmann::json(nullptr)
                                                                            : nlohmann::json(calibration->second)},
                         {"ceiling", ceiling < 0 ? nlohmann::json(nullptr) : nlohmann::json(ceiling)}});
  report.md += "| " + f.held_out + " | " + join(f.training, ", ") + " | " + variant + " (" +
               join(model.encoder().channels, ",") + ") | " + std::to_string(place.measured.size()) + " | " +
               fmt(su.mae) + " | " + fmt(lookups.best) + " (" + lookups.best_name + ") | " + fmt(global) + " | " +
               fmt(su.intersection, 3) + " | " + fmt(lookups.beam_intersection, 3) + " | " +
               (ceiling < 0 ? "n/a" : fmt(ceiling, 3)) + " | " +
               (ceiling < 0 ? "n/a" : fmt(su.intersection / ceiling, 2)) + " | " + (draws.empty() ? "–" : drawn_md) +
               " | " + (draws.empty() || ceiling < 0 ? "–" : fmt(drawn_mean / ceiling, 2)) + " |\n";
  std::fprintf(stderr, "intensity_places: %s held out, %s: UNet MAE %.4f, best lookup %.4f (%s), hist %.3f / %.3f%s%s\n",
               f.held_out.c_str(), variant.c_str(), su.mae, lookups.best, lookups.best_name.c_str(), su.intersection,
               ceiling, draws.empty() ? "" : ", sampled ", drawn_md.c_str());
}

const data::PlacedSet& set_named(const std::vector<data::PlacedSet>& sets, const std::string& name) {
  for (const auto& s : sets)
    if (s.name == name) return s;
  throw Error("no set named " + name);
}

// One held-out place: its lookups once, then every checkpoint variant trained without it.
void score_fold(const data::PlaceFold& f, const std::vector<data::PlacedSet>& sets, const fs::path& models,
                const std::vector<std::string>& variants, const std::vector<std::uint64_t>& seeds, Report& report) {
  const data::PlacedSet& held = set_named(sets, f.held_out);
  std::vector<data::PlacedSet> train;
  for (const auto& n : f.training) train.push_back(set_named(sets, n));
  data::check_no_place_leak(held, train);
  std::fprintf(stderr, "intensity_places: %s held out; trained on %s\n", f.held_out.c_str(),
               f.training.empty() ? "(none compatible)" : join(f.training, ", ").c_str());
  if (f.training.empty()) {
    report.rows.push_back({{"held_out", f.held_out}, {"training", f.training}, {"excluded", f.excluded}});
    report.md += "| " + f.held_out + " | none (below) | – | – | – | – | – | – | – | – | – | – | – |\n";
    return;
  }
  const data::Dataset held_ds = data::read_dataset(held.path);
  std::vector<data::Dataset> train_ds;
  for (const auto& s : train) train_ds.push_back(data::read_dataset(s.path));
  const HeldOutPlace place = measured_place(held_ds);
  std::fprintf(stderr, "intensity_places: %s held out: lookups...\n", f.held_out.c_str());
  const Lookups lookups = score_lookups(train_ds, held_ds, place.measured);
  for (const std::string& variant : variants)
    score_variant(f, held, held_ds, place, lookups, models, variant, seeds, report);
}

std::vector<data::PlacedSet> read_sets(const std::string& list) {
  std::vector<data::PlacedSet> sets;
  for (const std::string& item : split_list(list)) {
    const auto eq = item.find('=');
    if (eq == std::string::npos) throw Error("--data: \"" + item + "\" is not name=file.h5");
    sets.push_back(data::read_placed_set(item.substr(0, eq), item.substr(eq + 1)));
  }
  return sets;
}

}  // namespace

int main(int argc, char** argv) {
  cxxopts::Options opts("bench_intensity_places", "intensity held out by place (scripts/intensity_places.sh)");
  opts.add_options()("data", "name=dataset.h5,... one import per place", cxxopts::value<std::string>())(
      "plan", "print the folds and exit")("models", "folder of <held>.<variant>.h5 checkpoints",
                                          cxxopts::value<std::string>()->default_value(""))(
      "variants", "checkpoint variants, names",
      cxxopts::value<std::string>()->default_value("rcm,range"))(
      "out", "output prefix: PREFIX.json, PREFIX.md", cxxopts::value<std::string>()->default_value(""))(
      "seeds", "draw seeds for checkpoints with a spread head", cxxopts::value<std::string>()->default_value("1,2,3"))(
      "h,help", "help");
  try {
    const auto args = opts.parse(argc, argv);
    if (args.count("help") || !args.count("data")) {
      std::printf("%s", opts.help().c_str());
      return args.count("help") ? 0 : 2;
    }
    const std::vector<data::PlacedSet> sets = read_sets(args["data"].as<std::string>());
    const auto folds = data::place_folds(sets);
    if (args.count("plan")) {
      for (const auto& f : folds)
        std::printf("fold|%s|%s|%s\n", f.held_out.c_str(), join(f.training, ",").c_str(),
                    join(f.excluded, "; ").c_str());
      return 0;
    }
    const fs::path models = args["models"].as<std::string>();
    const std::string prefix = args["out"].as<std::string>();
    if (models.empty() || prefix.empty()) throw Error("--models and --out are needed unless --plan");
    std::vector<std::uint64_t> seeds;
    for (const std::string& seed : split_list(args["seeds"].as<std::string>())) seeds.push_back(std::stoull(seed));
    Report report;
    for (const auto& f : folds)
      score_fold(f, sets, models, split_list(args["variants"].as<std::string>()), seeds, report);
    std::string excluded_md;
    for (const auto& f : folds)
      for (const auto& e : f.excluded) excluded_md += "- " + f.held_out + " held out, not trained on " + e + "\n";
    write_file_atomically(prefix + ".json", nlohmann::json{{"rows", report.rows}}.dump(2) + "\n");
    write_file_atomically(prefix + ".md", report.md + "\n" + excluded_md);
    std::printf("%s", report.md.c_str());
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "error: %s\n", e.what());
    return 1;
  }
}
