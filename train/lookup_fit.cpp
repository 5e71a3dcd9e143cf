#include "train/lookup_fit.h"

#include <algorithm>
#include <string>

#include "common/error.h"
#include "data/baselines.h"
#include "pgm/materials.h"

namespace lidarsim::train {

nn::LookupBaseConfig lookup_base_config(const pgm::EncoderConfig& encoder, int rows) {
  const std::vector<std::string> names = encoder.input_names();
  nn::LookupBaseConfig c;
  const auto range = std::find(names.begin(), names.end(), "range");
  const auto first_class = std::find_if(names.begin(), names.end(), [](const std::string& n) { return n.rfind("class:", 0) == 0; });
  if (range == names.end() || first_class == names.end() || !encoder.class_one_hot)
    throw Error("lidar-train: --lookup-base needs the range channel and one-hot class channels in --channels (e.g. range,class,material)");
  c.classes = static_cast<int>(encoder.class_groups.size());
  c.class_channel = static_cast<int>(first_class - names.begin());
  c.range_channel = static_cast<int>(range - names.begin());
  c.range_bins = data::kRangeBins;
  c.bin_width = static_cast<float>(data::kRangeBinM / encoder.range_max_m);
  c.rows = rows;
  return c;
}

std::vector<pgm::ClassGroup> one_group_per_class() {
  std::vector<pgm::ClassGroup> groups;
  for (int id = 0; id < pgm::cls::count; ++id) groups.push_back({pgm::class_name(id), {id}});
  return groups;
}

LookupFit fit_lookup_base(const nn::LookupBaseConfig& config, const TrainingFrames& frames, int cols,
                          BeamFit beam_fit) {
  const int keys_n = (config.classes + 1) * config.range_bins;
  std::vector<double> sum(static_cast<std::size_t>(keys_n)), group_sum(static_cast<std::size_t>(config.classes + 1));
  std::vector<long> count(sum.size()), group_count(group_sum.size());
  double total = 0;
  long cells = 0;
  struct Cell {
    std::int32_t key;
    int row;
    float y;
  };
  std::vector<Cell> kept;
  nn::Tensor x, y, m;
  std::vector<std::int32_t> keys;
  for (int f = 0; f < frames.size(); ++f) {
    x.resize({1, frames.input_channels(), config.rows, cols});
    y.resize({1, 1, config.rows, cols});
    m.resize({1, 1, config.rows, cols});
    frames.fill(Sample{f, 0, false}, x, y, m, 0);
    nn::lookup_base_keys(keys, x, config);
    for (std::size_t i = 0; i < keys.size(); ++i) {
      if (m.data()[i] <= 0 || keys[i] < 0) continue;  // not a training cell
      const double v = y.data()[i];
      sum[keys[i]] += v, ++count[keys[i]];
      group_sum[keys[i] / config.range_bins] += v, ++group_count[keys[i] / config.range_bins];
      total += v, ++cells;
      kept.push_back({keys[i], static_cast<int>(i / cols), y.data()[i]});
    }
  }
  if (cells == 0) throw Error("lidar-train: --lookup-base: no training cells with a return to fit the table on");
  LookupFit fit;
  fit.cells = cells;
  fit.table.resize(sum.size());
  const double global = total / cells;
  for (int k = 0; k < keys_n; ++k) {
    const int g = k / config.range_bins;
    const double fallback = group_count[g] ? group_sum[g] / group_count[g] : global;
    fit.table[k] = static_cast<float>(count[k] ? sum[k] / count[k] : fallback);
  }
  // Residuals over the table; for the loop's form in double, as the loop computes them from its
  // double means (the mean form keeps its earlier float table, bit for bit).
  auto table_mean = [&](int k) -> double {
    if (beam_fit == BeamFit::mean) return fit.table[k];
    const int g = k / config.range_bins;
    return count[k] ? sum[k] / count[k] : group_count[g] ? group_sum[g] / group_count[g] : global;
  };
  std::vector<double> resid(kept.size());
  for (std::size_t i = 0; i < kept.size(); ++i) resid[i] = kept[i].y - table_mean(kept[i].key);
  double lo = -1e300, hi = 1e300, shrink = 0;
  if (beam_fit == BeamFit::loop) {
    // qualify/residual.h winsor_limits (q = 0.01) and fit_table's shrinkage (5).
    shrink = 5;
    if (resid.size() >= 10) {
      std::vector<double> sorted = resid;
      std::sort(sorted.begin(), sorted.end());
      lo = sorted[static_cast<std::size_t>(0.01 * (sorted.size() - 1))];
      hi = sorted[static_cast<std::size_t>(0.99 * (sorted.size() - 1))];
    }
  }
  std::vector<double> row_sum(static_cast<std::size_t>(config.rows));
  std::vector<long> row_count(row_sum.size());
  for (std::size_t i = 0; i < kept.size(); ++i) row_sum[kept[i].row] += std::clamp(resid[i], lo, hi), ++row_count[kept[i].row];
  fit.beam.resize(row_sum.size());
  for (int r = 0; r < config.rows; ++r)
    fit.beam[r] = row_count[r] ? static_cast<float>(row_sum[r] / (row_count[r] + shrink)) : 0.f;
  return fit;
}

void set_lookup_base(nn::UNet& model, const LookupFit& fit) {
  nn::ParamArena& p = model.params();
  const int table = p.find("lookup/table"), beam = p.find("lookup/beam");
  if (table < 0 || beam < 0 || p.info(table).shape.numel() != fit.table.size() || p.info(beam).shape.numel() != fit.beam.size())
    throw Error("set_lookup_base: the model's lookup base does not match the fit");
  std::copy(fit.table.begin(), fit.table.end(), p.value(table));
  std::copy(fit.beam.begin(), fit.beam.end(), p.value(beam));
}

}  // namespace lidarsim::train
