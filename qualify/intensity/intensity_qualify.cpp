// Intensity cells, the lookups, and `lidar-qualify intensity` (a checkpoint against measured
// intensity on the held-out cells); the helpers the loop shares.
#include "qualify/intensity/intensity.h"
#include "qualify/intensity/intensity_internal.h"

#include <algorithm>
#include <array>
#include <cstdio>
#include <cmath>
#include <map>
#include <sstream>

#include "common/atomic_file.h"
#include "common/error.h"
#include "data/baselines.h"
#include "data/import.h"
#include "data/split.h"
#include "infer/intensity_model.h"
#include "nn/checkpoint.h"
#include "nn/receptive_field.h"
#include "pgm/materials.h"
#include "qualify/report.h"
#include "qualify/residual.h"
#include "qualify/similarity.h"
#include "qualify/windows.h"
#include "train/trainer.h"

namespace fs = std::filesystem;

namespace lidarsim::qualify {

namespace intensity_detail {

Errors errors(const std::vector<double>& pred, const std::vector<double>& meas, const std::vector<size_t>& idx) {
  Errors e;
  for (size_t i : idx) {
    const double d = pred[i] - meas[i];
    e.mae += std::abs(d);
    e.rmse += d * d;
    ++e.n;
  }
  if (e.n) e.mae /= e.n, e.rmse = std::sqrt(e.rmse / e.n);
  return e;
}

Errors errors(const std::vector<double>& pred, const std::vector<double>& meas) {
  std::vector<size_t> all(meas.size());
  for (size_t i = 0; i < all.size(); ++i) all[i] = i;
  return errors(pred, meas, all);
}

std::vector<size_t> held_indices(const IntensityCells& c, int cls) {
  std::vector<size_t> idx;
  for (size_t i = 0; i < c.size(); ++i)
    if (c.held_out[i] && (cls < 0 || c.cls[i] == cls)) idx.push_back(i);
  return idx;
}

std::vector<double> pick(const std::vector<double>& v, const std::vector<size_t>& idx) {
  std::vector<double> o(idx.size());
  for (size_t k = 0; k < idx.size(); ++k) o[k] = v[idx[k]];
  return o;
}

}  // namespace intensity_detail

namespace {

using namespace intensity_detail;

const std::vector<std::string> kLoopChannels = {"elevation", "azimuth", "height", "incidence", "depth_discontinuity"};

}  // namespace

data::Dataset import_for_qualify(const fs::path& dir, std::vector<std::string> extra) {
  data::ImportOptions opt;
  for (const auto& ch : kLoopChannels)
    if (std::find(extra.begin(), extra.end(), ch) == extra.end()) extra.push_back(ch);
  opt.extra_channels = extra;
  // A KITTI object folder (velodyne/, label_2/, calib/): frames from different drives, for
  // validating across places (--split frames:...).
  if (fs::is_directory(dir / "label_2") && fs::is_directory(dir / "calib")) return data::import_kitti_object(dir, opt);
  return data::import_semantickitti(dir, opt);
}

data::SectorSplit intensity_split(const data::Dataset& ds, const std::string& spec, int depth) {
  return data::parse_split(spec, nn::receptive_field_half_width({1, 1, 8, depth}), ds.cols());
}

IntensityCells intensity_cells(const data::Dataset& ds, const data::SectorSplit& split) {
  IntensityCells c;
  c.feature.assign(kIntensityFeatures.size(), {});
  const int H = ds.rows(), W = ds.cols(), N = ds.size();
  const int ir = ds.channel_index("range"), ic = ds.channel_index("class"), im = ds.channel_index("material");
  const int iinc = ds.channel_index("incidence"), iel = ds.channel_index("elevation"), iaz = ds.channel_index("azimuth"),
            ih = ds.channel_index("height"), idd = ds.channel_index("depth_discontinuity");
  const int C = ds.pgm.shape().c;
  const float* P = ds.pgm.data();
  const float* T = ds.target.data();
  const float* M = ds.mask.data();
  std::vector<int> region_of_column(W);  // split.region_of, a search over the regions' columns, once per column
  for (int col = 0; col < W; ++col) region_of_column[col] = split.region_of(col, W);
  for (int n = 0; n < N; ++n) {
    const auto roles = split.roles(W, n < static_cast<int>(ds.frames.size()) ? ds.frames[n] : "");
    auto ch = [&](int k, int r, int col) { return P[((static_cast<size_t>(n) * C + k) * H + r) * W + col]; };
    auto has = [&](int r, int col) { return M[(static_cast<size_t>(n) * H + r) * W + col] > 0; };
    for (int r = 0; r < H; ++r)
      for (int col = 0; col < W; ++col) {
        if (!has(r, col) || roles[col] == data::kGuard) continue;
        const double range = ch(ir, r, col);
        c.measured.push_back(T[(static_cast<size_t>(n) * H + r) * W + col]);
        c.frame.push_back(n);
        // Bootstrap block: a held-out frame (a place) when whole frames are held out, else a strip.
        c.sector.push_back(split.validation_frames.empty() ? col / 16 : 100000 + n);
        const bool held = roles[col] == data::kValidation;
        c.region.push_back(held ? std::max(0, region_of_column[col]) : -1);
        c.row.push_back(r);
        c.held_out.push_back(held);
        c.cls.push_back(static_cast<int>(ch(ic, r, col)));
        c.cell.push_back((static_cast<long>(n) * H + r) * W + col);
        const double f[9] = {range,           ch(iinc, r, col), ch(iel, r, col), ch(iaz, r, col), ch(ih, r, col),
                             ch(ic, r, col),  ch(im, r, col),   ch(idd, r, col), static_cast<double>(r)};
        for (size_t k = 0; k < 9; ++k) c.feature[k].push_back(f[k]);
      }
  }
  if (c.size() == 0) throw Error("qualify intensity: the scans have no returns");
  bool fit = false, held = false;
  for (char h : c.held_out) (h ? held : fit) = true;
  if (!fit || !held) throw Error("qualify intensity: need cells in both fit and held-out sectors");
  return c;
}

std::vector<double> lookup_prediction(const IntensityCells& c) {
  double sum = 0;
  long n = 0;
  for (size_t i = 0; i < c.size(); ++i)
    if (!c.held_out[i]) sum += c.measured[i], ++n;
  const std::vector<double> global(c.size(), n ? sum / n : 0);
  const auto by_class = lookup(c, [&](size_t i) { return long(c.cls[i]); }, global);
  return lookup(c, [&](size_t i) { return long(c.cls[i]) * 1000 + data::range_bin(c.feature[0][i]); }, by_class);
}

std::vector<double> lookup_beam_prediction(const IntensityCells& c, int rows) {
  const std::vector<double> base = lookup_prediction(c);
  std::vector<double> x, r;
  for (size_t i = 0; i < c.size(); ++i)
    if (!c.held_out[i]) x.push_back(c.row[i]), r.push_back(c.measured[i] - base[i]);
  const Winsor w = winsor_limits(r);
  for (double& v : r) v = w(v);
  const BinnedTable beam = fit_table(category_edges(rows), x, r);
  std::vector<double> out(c.size());
  for (size_t i = 0; i < c.size(); ++i) out[i] = base[i] + beam(c.row[i]);
  return out;
}

namespace {

// The model's prediction at every cell of `c`, one scan at a time.
std::vector<double> predict_cells(infer::IntensityModel& model, const data::Dataset& ds, const IntensityCells& c) {
  std::vector<float> out;
  const int cells = ds.rows() * ds.cols();
  std::vector<std::vector<float>> frames(ds.size());
  for (int n = 0; n < ds.size(); ++n) {
    model.predict(ds.frame_pgm(n), out);
    frames[n] = out;
  }
  std::vector<double> pred(c.size());
  for (size_t i = 0; i < c.size(); ++i) pred[i] = frames[c.frame[i]][c.cell[i] % cells];
  return pred;
}

struct SectionResult {
  nlohmann::json summary;
  std::vector<double> predicted, measured;
};

// Errors and similarity of the held-out cells of one class (-1: all), with the real-vs-real
// ceilings: the same regions in alternate scans (the sensor's repeatability on nearly the same
// scene), and the two validation regions of the same scans against each other (different scenery,
// so a low bar rather than a ceiling; n/a with one region).
SectionResult qualify_section(const IntensityCells& c, int scans, std::size_t regions, const std::vector<double>& pred,
                              const std::vector<double>& base, int cls) {
  SectionResult r;
  const auto idx = held_indices(c, cls);
  std::vector<std::vector<double>> by_scan(scans), by_sector(regions > 1 ? regions : 1);
  for (size_t i : idx) {
    r.predicted.push_back(pred[i]), r.measured.push_back(c.measured[i]);
    by_scan[c.frame[i]].push_back(c.measured[i]);
    by_sector[std::min<size_t>(c.region[i], by_sector.size() - 1)].push_back(c.measured[i]);
  }
  Similarity s = compare(r.predicted, r.measured);
  s.ceiling = real_vs_real_ceiling(by_scan);
  const double sector_ceiling = real_vs_real_ceiling(by_sector);
  const Errors e = errors(pred, c.measured, idx), b = errors(base, c.measured, idx);
  nlohmann::json sj = to_json(s);
  sj["ceiling_between_sectors"] = sector_ceiling < 0 ? nlohmann::json(nullptr) : nlohmann::json(sector_ceiling);
  r.summary = {{"cells", e.n}, {"mae", e.mae}, {"rmse", e.rmse}, {"similarity", sj},
               {"lookup_class_x_range", {{"mae", b.mae}, {"rmse", b.rmse}}}};
  return r;
}

void write_report_header(std::ostream& md, const fs::path& checkpoint, int scans, const fs::path& dir, int half_width,
                         const std::string& split) {
  md << "# Intensity model qualification: predicted vs measured\n\nCheckpoint " << checkpoint.string() << "; "
     << scans << " scans from " << dir.string() << "; receptive field half-width " << half_width
     << " columns; held-out cells = " << split
     << ". The model must have been trained on this split's training cells (lidar-train's default) for the "
        "figures to be held out.\n\n"
     << "Similarity = histogram intersection (1 - total variation) of predicted and measured intensity on shared bins "
        "(40 bins over the pooled 1st-99th percentile + 2 overflow bins) with a basic-bootstrap 95% interval for the "
        "similarity of the two distributions (sampling noise lowers an intersection, so the interval can lie above "
        "the sample's value); ceiling = "
        "measured intensity of the held-out regions in scans 1, 3, ... vs scans 2, 4, ... (real vs real: the sensor's "
        "repeatability on nearly the same scene; n/a with one scan); sectors = measured intensity of the two validation "
        "regions against each other (different scenery: a low bar, not a ceiling).\n\n"
     << "| class | cells | MAE | RMSE | lookup MAE (class x range) | similarity [95%] | ceiling | sectors | KS | "
        "Wasserstein |\n|---|---|---|---|---|---|---|---|---|---|\n";
}

void write_report_row(std::ostream& md, const std::string& name, const nlohmann::json& s) {
  const auto& sim = s["similarity"];
  md << "| " << name << " | " << s["cells"].get<long>() << " | " << fmt(s["mae"].get<double>(), 4) << " | "
     << fmt(s["rmse"].get<double>(), 4) << " | " << fmt(s["lookup_class_x_range"]["mae"].get<double>(), 4) << " | "
     << fmt(sim["intersection"].get<double>()) << " [" << fmt(sim["interval95"][0].get<double>(), 2) << ", "
     << fmt(sim["interval95"][1].get<double>(), 2) << "] | "
     << (sim.contains("ceiling") ? fmt(sim["ceiling"].get<double>()) : "n/a") << " | "
     << (sim["ceiling_between_sectors"].is_number() ? fmt(sim["ceiling_between_sectors"].get<double>()) : "n/a")
     << " | " << fmt(sim["ks"].get<double>()) << " | " << fmt(sim["wasserstein"].get<double>(), 4) << " |\n";
}

}  // namespace

nlohmann::json qualify_intensity(const fs::path& checkpoint, const fs::path& dir, const fs::path& out_dir) {
  infer::IntensityModel model = infer::IntensityModel::load(checkpoint);
  const data::Dataset ds = import_for_qualify(dir, model.extra_channels());
  const int depth = nn::read_checkpoint_meta(checkpoint).unet.depth;
  const int half_width = nn::receptive_field_half_width({1, 1, 8, depth});
  const data::SectorSplit split = intensity_split(ds, "guarded", depth);
  const IntensityCells c = intensity_cells(ds, split);
  const std::vector<double> pred = predict_cells(model, ds, c);
  const std::vector<double> base = lookup_prediction(c);
  fs::create_directories(out_dir);
  nlohmann::json j;
  j["checkpoint"] = checkpoint.string();
  j["frames"] = ds.frames;
  j["split"] = split.describe(ds.cols());
  j["receptive_field_half_width"] = half_width;
  const SectionResult all = qualify_section(c, ds.size(), split.regions.size(), pred, base, -1);
  j["overall"] = all.summary;
  std::ostringstream md;
  write_report_header(md, checkpoint, ds.size(), dir, half_width, split.describe(ds.cols()));
  write_report_row(md, "all", all.summary);
  std::map<int, long> counts;
  for (size_t i = 0; i < c.size(); ++i)
    if (c.held_out[i]) ++counts[c.cls[i]];
  nlohmann::json per = nlohmann::json::object();
  for (const auto& [cls, n] : counts) {
    if (n < 50) continue;
    const nlohmann::json s = qualify_section(c, ds.size(), split.regions.size(), pred, base, cls).summary;
    per[pgm::class_name(cls)] = s;
    write_report_row(md, pgm::class_name(cls), s);
  }
  j["per_class"] = per;
  const std::string caption = write_histogram_png(
      out_dir / "hist_intensity.png", all.predicted, all.measured,
      {"Intensity of held-out cells: predicted vs measured", "intensity (0..1)", "share of samples", "predicted"},
      all.summary["similarity"]["intersection"].get<double>());
  md << "\n![predicted vs measured intensity](hist_intensity.png)\n\n" << caption << "\n";
  write_file_atomically(out_dir / "report.md", md.str());
  write_file_atomically(out_dir / "report.json", j.dump(2) + "\n");
  return j;
}

}  // namespace lidarsim::qualify
