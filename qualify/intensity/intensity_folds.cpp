// The intensity loop's folds, its base models per fold, and the pooled held-out cells.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <set>

#include "common/error.h"
#include "qualify/intensity/intensity_internal.h"

namespace lidarsim::qualify::intensity_detail {

namespace {

// The PGM channel that carries each vocabulary feature into the UNet.
std::string channel_of(const std::string& feature) {
  if (feature == "incidence_angle") return "incidence";
  return feature;  // elevation, azimuth, height, depth_discontinuity; range, class, material
}

// The scans rolled by `shift` columns: out column c holds in column (c + shift) mod W.
data::Dataset rolled(const data::Dataset& ds, int shift) {
  if (shift == 0) return ds;
  data::Dataset out = ds;
  const int N = ds.size(), H = ds.rows(), W = ds.cols();
  auto roll = [&](const nn::Tensor& in, nn::Tensor& o) {
    const int planes = N * in.shape().c * H;
    for (int p = 0; p < planes; ++p) {
      const float* src = in.data() + static_cast<size_t>(p) * W;
      float* dst = o.data() + static_cast<size_t>(p) * W;
      for (int c = 0; c < W; ++c) dst[c] = src[(c + shift) % W];
    }
  };
  roll(ds.pgm, out.pgm);
  roll(ds.target, out.target);
  roll(ds.mask, out.mask);
  if (!ds.point_index.empty())
    for (size_t p = 0; p < static_cast<size_t>(N) * H; ++p)
      for (int c = 0; c < W; ++c) out.point_index[p * W + c] = ds.point_index[p * W + (c + shift) % W];
  return out;
}

}  // namespace

double scan_pair_correlation(const data::Dataset& ds, int a, int b) {
  const int H = ds.rows(), W = ds.cols(), ir = ds.channel_index("range");
  double sab = 0, saa = 0, sbb = 0;
  for (int r = 0; r < H; ++r) {
    double ma = 0, mb = 0, k = 0;
    auto both = [&](int c) { return ds.mask.at(a, 0, r, c) > 0 && ds.mask.at(b, 0, r, c) > 0; };
    for (int c = 0; c < W; ++c)
      if (both(c)) ma += ds.pgm.at(a, ir, r, c), mb += ds.pgm.at(b, ir, r, c), ++k;
    if (k < 2) continue;
    ma /= k, mb /= k;
    for (int c = 0; c < W; ++c)
      if (both(c)) {
        const double u = ds.pgm.at(a, ir, r, c) - ma, v = ds.pgm.at(b, ir, r, c) - mb;
        sab += u * v, saa += u * u, sbb += v * v;
      }
  }
  return saa > 0 && sbb > 0 ? sab / std::sqrt(saa * sbb) : 0;
}

double scenery_correlation(const data::Dataset& ds) {
  // Near 1 for scans of one street 0.1 s apart, near 0 for scans of different scenes.
  if (ds.size() < 2) return 0;
  double sum = 0;
  for (int n = 0; n + 1 < ds.size(); ++n) sum += scan_pair_correlation(ds, n, n + 1);
  return sum / (ds.size() - 1);
}

TimeBlocks time_blocks(const data::Dataset& ds, int blocks) {
  TimeBlocks t;
  const int n = ds.size();
  t.blocks = std::min(blocks, n);
  for (int f = 0; f < n; ++f) t.block_of_frame.push_back(f * t.blocks / std::max(1, n));
  if (t.blocks < 2) return t;
  double sum = 0;
  long pairs = 0;
  for (int a = 0; a < n; ++a)
    for (int b = a + 1; b < n; ++b)
      if (t.block_of_frame[a] != t.block_of_frame[b]) sum += scan_pair_correlation(ds, a, b), ++pairs;
  t.cross_correlation = pairs ? sum / pairs : 0;
  return t;
}

std::vector<std::string> channels_of(const std::string& feature) {
  // Azimuth as sine and cosine, a periodic feature, so that validation azimuths between training
  // azimuths are interpolation (the raw angle would have to be extrapolated across the guarded
  // regions). beam_row enters as a per-row affine layer instead (the loop's refit step).
  if (feature == "azimuth") return {"azimuth_sin", "azimuth_cos"};
  return {channel_of(feature)};
}

data::Dataset with_derived_channels(const data::Dataset& ds, const std::vector<std::string>& names) {
  std::vector<std::string> add;
  for (const auto& n : names)
    if ((n == "azimuth_sin" || n == "azimuth_cos") &&
        std::find(ds.channels.begin(), ds.channels.end(), n) == ds.channels.end())
      add.push_back(n);
  if (add.empty()) return ds;
  data::Dataset out = ds;
  const int N = ds.size(), C = ds.pgm.shape().c, H = ds.rows(), W = ds.cols();
  const int iaz = ds.channel_index("azimuth");
  out.pgm.resize({N, C + static_cast<int>(add.size()), H, W});
  for (int n = 0; n < N; ++n) {
    for (int k = 0; k < C; ++k) std::copy(ds.pgm.channel(n, k), ds.pgm.channel(n, k) + H * W, out.pgm.channel(n, k));
    for (size_t a = 0; a < add.size(); ++a)
      for (int r = 0; r < H; ++r)
        for (int col = 0; col < W; ++col) {
          const double az = ds.pgm.at(n, iaz, r, col);
          out.pgm.at(n, C + static_cast<int>(a), r, col) =
              static_cast<float>(add[a] == "azimuth_sin" ? std::sin(az) : std::cos(az));
        }
  }
  for (const auto& n : add) out.channels.push_back(n);
  return out;
}

UnetFits fit_unets(const data::Dataset& ds, const IntensityCells& c, const std::vector<std::string>& channels,
                   const IntensityLoopOptions& o, const std::string& label, TrainingCount& count, bool row_affine) {
  UnetFits fits;
  pgm::EncoderConfig encoder;
  encoder.channels = channels;
  fits.ensemble.assign(c.size(), 0.0);
  const int cells = ds.rows() * ds.cols();
  for (int k = 0; k < o.unet.seeds; ++k) {
    train::TrainConfig t;
    t.encoder = encoder;
    t.base = o.unet.base, t.depth = o.unet.depth;
    t.row_affine = row_affine;
    t.lookup_base = o.unet.lookup_base;
    t.lookup_form = "classes";
    t.epochs = 1, t.steps_per_epoch = o.unet.steps;
    t.batch = o.unet.batch, t.crop_columns = o.unet.crop_columns;
    t.lr = o.unet.lr, t.lambda = o.unet.lambda;
    t.seed = static_cast<std::uint64_t>(k + 1);
    t.threads = o.unet.threads;
    t.out.clear();
    t.progress = o.progress;
    t.split = o.split;
    if (o.progress)
      std::fprintf(stderr, "loop intensity: UNet %d/%d (%s, seed %d, %d steps)\n", ++count.done, count.total,
                   label.c_str(), k + 1, o.unet.steps);
    train::TrainResult r = train::train_on(t, {&ds}, {"scans"});
    // The encoder the model was trained with (a lookup base keys its class input by every class).
    const nn::Tensor pred = train::predict_dataset(
        *r.model, pgm::EncoderConfig::from_json(r.meta.attributes.at("encoder"), "loop UNet encoder"), ds);
    std::vector<double> p(c.size());
    for (size_t i = 0; i < c.size(); ++i) p[i] = pred.image(c.frame[i])[c.cell[i] % cells];
    for (size_t i = 0; i < c.size(); ++i) fits.ensemble[i] += p[i] / o.unet.seeds;
    fits.seed_pred.push_back(std::move(p));
    if (k == 0) fits.first = std::move(r);
  }
  return fits;
}

std::vector<Fold> make_folds(const data::Dataset& ds, const data::SectorSplit& split, int folds) {
  if (folds != 1 && folds != 4)
    throw Error("loop intensity: --folds " + std::to_string(folds) +
                ": expected 1 (the guarded split's regions as they are) or 4 (the regions rotated by an eighth of "
                "the circle per fold, so that every column is validated once)");
  if (folds > 1 && (split.regions.empty() || !split.validation_frames.empty()))
    throw Error("loop intensity: --folds " + std::to_string(folds) + ": rotating folds need a guarded region split, got " +
                split.describe(ds.cols()));
  // The guarded split validates a quarter of the circle (two regions of W/8 half a turn apart, or
  // one of W/4): rotated by their width four times, the regions tile the circle.
  const double width = ds.cols() / (4.0 * std::max<size_t>(1, split.regions.size()));
  std::vector<Fold> out(folds);
  for (int k = 0; k < folds; ++k) {
    Fold& f = out[k];
    f.shift = static_cast<int>(std::lround(k * width)) % ds.cols();
    f.ds = rolled(ds, f.shift);
    f.cells = intensity_cells(f.ds, split);
    f.held = held_indices(f.cells);
  }
  return out;
}

Pooled pool(const std::vector<Fold>& folds, int W, double scenery, const TimeBlocks& time) {
  Pooled p;
  p.scenery_correlation = scenery;
  p.time_block_correlation = time.cross_correlation;
  p.feature.assign(kIntensityFeatures.size(), {});
  std::vector<int> region;
  for (size_t k = 0; k < folds.size(); ++k) {
    const Fold& f = folds[k];
    p.offset.push_back(p.size());
    const std::vector<double> lk = lookup_prediction(f.cells);
    for (size_t i : f.held) {
      const IntensityCells& c = f.cells;
      p.measured.push_back(c.measured[i]);
      p.lookup.push_back(lk[i]);
      for (size_t q = 0; q < kIntensityFeatures.size(); ++q) p.feature[q].push_back(c.feature[q][i]);
      p.fold.push_back(static_cast<int>(k));
      p.frame.push_back(c.frame[i]);
      p.row.push_back(c.row[i]);
      p.cls.push_back(c.cls[i]);
      const int col = static_cast<int>((c.cell[i] % W + f.shift) % W);  // the original column
      p.block.push_back(c.sector[i] >= 100000 ? c.sector[i] : col / 16);
      region.push_back(c.region[i]);
    }
  }
  p.offset.push_back(p.size());
  // Cross-fit groups for the candidate forms: a sensor-fixed effect (a laser, a window of
  // azimuth) repeats in every scan at the same cells, so a form fitted on the other scans'
  // held-out residual predicts it on this scan's. Unless the scans show the same scenery at the
  // same cells (consecutive scans of one street): then the base's error on that scenery repeats
  // as well and would pass for an effect of the cells. Then blocks of consecutive scans are the
  // groups if scans of different blocks do not share it (a drive long enough), else the folds
  // (other columns): a table of a row carries to other columns, a table of azimuth does not (its
  // held-out columns are columns it never fitted), so azimuth is cross-fitted over classes x row
  // blocks in the same columns instead (scenery_cross_fit), or left undecided.
  const std::set<int> frames(p.frame.begin(), p.frame.end()), regions(region.begin(), region.end());
  std::vector<int> time_block;
  for (int f : p.frame) time_block.push_back(time.block_of_frame.empty() ? 0 : time.block_of_frame.at(f));
  const std::vector<int>* by = nullptr;
  if (frames.size() >= 2 && scenery < kSameSceneryCorrelation) {
    by = &p.frame, p.group_by = "scan";
  } else if (time.blocks >= 2 && time.cross_correlation < kSameSceneryCorrelationBetweenBlocks) {
    by = &time_block, p.group_by = "time block (" + std::to_string(time.blocks) + " blocks of consecutive scans)";
  } else if (folds.size() >= 2) {
    by = &p.fold, p.group_by = "fold";
  } else if (regions.size() >= 2) {
    by = &region, p.group_by = "validation region";
  }
  std::string columns_reason;
  if (!by || by == &p.fold || by == &region) {
    char corr[96];
    std::snprintf(corr, sizeof corr, "range correlation %.2f between consecutive scans, %.2f between time blocks",
                  scenery, time.cross_correlation);
    columns_reason =
        (frames.size() < 2 ? std::string("1 scan")
                           : std::to_string(frames.size()) + " scans of the same scenery (" + corr + ")") +
        ", so the forms are cross-fitted over columns, and an azimuth form cannot be judged on columns it never "
        "fitted";
  }
  if (by) {
    std::map<int, int> id;
    for (int v : *by) id.emplace(v, static_cast<int>(id.size()));
    for (int v : *by) p.group.push_back(id[v]);
    p.groups = static_cast<int>(id.size());
  } else {
    // One scan, one region: alternate 16-column strips.
    for (long b : p.block) p.group.push_back(static_cast<int>(b % 2));
    p.group_by = "alternate 16-column strips", p.groups = 2;
  }
  p.azimuth_columns = columns_reason;
  if (!columns_reason.empty()) scenery_cross_fit(p, columns_reason);
  return p;
}

std::vector<double> pool_prediction(const std::vector<Fold>& folds, const std::vector<std::vector<double>>& per_fold) {
  std::vector<double> out;
  for (size_t k = 0; k < folds.size(); ++k)
    for (size_t i : folds[k].held) out.push_back(per_fold[k][i]);
  return out;
}

// The scans of a block show the same street at the same columns: not independent, blocks nearly are.
std::array<double, 2> change_interval(const Pooled& p, const std::vector<double>& after) {
  std::map<long, std::array<double, 3>> blocks;  // block -> (sum |after error|, sum |before error|, n)
  for (size_t i = 0; i < p.size(); ++i) {
    auto& b = blocks[p.block[i]];
    b[0] += std::abs(after[i] - p.measured[i]);
    b[1] += std::abs(p.base[i] - p.measured[i]);
    b[2] += 1;
  }
  BlockSums bl;
  for (const auto& [k, v] : blocks) bl.push_back(v);
  return block_bootstrap_interval(
      bl, [](const std::array<double, 3>& s) { return s[2] > 0 ? (s[0] - s[1]) / s[2] : 0.0; }, 1000, 7);
}

}  // namespace lidarsim::qualify::intensity_detail
