#include "nn/checkpoint.h"

#include <hdf5.h>

#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstdlib>
#include <functional>
#include <vector>

#include "common/error.h"
#include "nn/checkpoint_image.h"
#include "nn/checkpoint_h5.h"
#include "nn/h5_memory_file.h"

namespace lidarsim::nn {
namespace {

using namespace checkpoint_h5;

// Format 1: one output, `unet.out_channels`. Format 2 (several outputs, or named heads): the output
// count is `unet.outputs` and `unet.out_channels` is left out, so builds that predate format 2
// (they read `unet.out_channels` and never read `format`) reject the file naming that attribute
// instead of loading a several-output model as a one-output one. A model format 1 describes is
// still written as format 1, byte for byte as before. Format 3 is format 2 with
// `unet.spread_scale`, the spread head's calibration factor (UNetConfig::spread_scale): builds that
// read formats 1-2 would load the weights and sample with the uncalibrated scale, so they refuse it
// by its format number; a model whose factor is 1 is still written as format 1 or 2. Format 4 is
// format 3 with `unet.spread_residual` (UNetConfig::spread_residual, JSON: the residual's
// quantiles per bin of the mean and the targets' grid): builds that read formats 1-3 would draw
// from the Laplace/Gaussian instead, so they refuse it by its number; without a table, 1-3 as before.
// Format 5 is format 4 (every field of it written, the table possibly empty) with a zero_logit head
// in `unet.heads` (nn/heads.h): the table is then fitted on the values that are not 0, so a build
// that reads 1-4 would draw without the zeros from a table that lacks them; it refuses the number.
constexpr const char* kFormatPrefix = "lidarsim-checkpoint ";
constexpr int kNewestCheckpointFormat = 5;

bool needs_format2(const UNetConfig& c) { return c.out_channels != 1 || !c.heads.empty(); }
bool needs_format3(const UNetConfig& c) { return c.spread_scale != 1.f; }
bool needs_format4(const UNetConfig& c) { return !c.spread_residual.empty(); }
bool needs_format5(const UNetConfig& c) { return head_channel(c.heads, HeadKind::zero_logit) >= 0; }

bool reserved_attribute(const std::string& key) {
  return key == "format" || key.rfind("unet.", 0) == 0 || key.rfind("optimizer.", 0) == 0;
}

int positive_int_attr(const Reader& r, const std::string& name) {
  const std::int64_t v = r.int_attr("config", name);
  if (v < 1 || v > 1 << 20) r.fail("config/" + name, "expected a positive integer, got " + std::to_string(v));
  return static_cast<int>(v);
}

// No attribute: no per-row affine layer.
int row_affine_rows(const Reader& r) {
  return r.has_attr("config", "unet.row_affine_rows") ? positive_int_attr(r, "unet.row_affine_rows") : 0;
}

// The lookup base's config (nn/unet.h): absent = none.
LookupBaseConfig lookup_config(const Reader& r) {
  LookupBaseConfig c;
  if (!r.has_attr("config", "unet.lookup.classes")) return c;
  c.classes = positive_int_attr(r, "unet.lookup.classes");
  c.range_bins = positive_int_attr(r, "unet.lookup.range_bins");
  c.rows = positive_int_attr(r, "unet.lookup.rows");
  for (auto [name, field] : {std::pair{"unet.lookup.class_channel", &c.class_channel}, {"unet.lookup.range_channel", &c.range_channel}}) {
    const std::int64_t v = r.int_attr("config", name);
    if (v < 0 || v > 1 << 20) r.fail(std::string("config/") + name, "expected an integer >= 0, got " + std::to_string(v));
    *field = static_cast<int>(v);
  }
  c.bin_width = static_cast<float>(r.double_attr("config", "unet.lookup.bin_width"));
  if (!(c.bin_width > 0) || !std::isfinite(c.bin_width))
    r.fail("config/unet.lookup.bin_width", "expected a finite number > 0, got " + std::to_string(c.bin_width));
  return c;
}

}  // namespace

void save_checkpoint(const std::filesystem::path& path, const UNet& model, const Optimizer* optimizer,
                     const Checkpoint& meta) {
  silence_hdf5();
  const ParamArena& params = model.params();
  for (const auto& [key, value] : meta.attributes)
    if (reserved_attribute(key) || key.empty())
      throw input_error(path.string(), "config/" + key, "attribute name is reserved or empty");
  if (optimizer && (optimizer->m().size() != params.size() || optimizer->v().size() != params.size()))
    throw input_error(path.string(), "optimizer", "state does not match the model's " +
                                                      std::to_string(params.size()) + " parameters");

  {
    Writer w(path);
    {
      Handle config = w.group("config");
      const bool v2 = needs_format2(model.config()), v5 = needs_format5(model.config()),
                 v4 = v5 || needs_format4(model.config()), v3 = v4 || needs_format3(model.config());
      w.attr(config.get(), "config", "format", kFormatPrefix + std::to_string(v5 ? 5 : v4 ? 4 : v3 ? 3 : v2 ? 2 : 1));
      w.attr(config.get(), "config", "unet.in_channels", std::int64_t{model.config().in_channels});
      if (!v2) w.attr(config.get(), "config", "unet.out_channels", std::int64_t{model.config().out_channels});
      if (v2) w.attr(config.get(), "config", "unet.outputs", std::int64_t{model.config().out_channels});
      if (!model.config().heads.empty()) w.attr(config.get(), "config", "unet.heads", heads_text(model.config().heads));
      if (v3) w.attr(config.get(), "config", "unet.spread_scale", static_cast<double>(model.config().spread_scale));
      if (v4) w.attr(config.get(), "config", "unet.spread_residual", spread_residual_json(model.config().spread_residual));
      w.attr(config.get(), "config", "unet.base", std::int64_t{model.config().base});
      w.attr(config.get(), "config", "unet.depth", std::int64_t{model.config().depth});
      // Only when present: a model without the layer writes no trace of it (read back as no layer).
      if (model.config().row_affine_rows > 0)
        w.attr(config.get(), "config", "unet.row_affine_rows", std::int64_t{model.config().row_affine_rows});
      if (const LookupBaseConfig& lk = model.config().lookup; lk.classes > 0) {
        w.attr(config.get(), "config", "unet.lookup.classes", std::int64_t{lk.classes});
        w.attr(config.get(), "config", "unet.lookup.class_channel", std::int64_t{lk.class_channel});
        w.attr(config.get(), "config", "unet.lookup.range_channel", std::int64_t{lk.range_channel});
        w.attr(config.get(), "config", "unet.lookup.range_bins", std::int64_t{lk.range_bins});
        w.attr(config.get(), "config", "unet.lookup.rows", std::int64_t{lk.rows});
        w.attr(config.get(), "config", "unet.lookup.bin_width", lk.bin_width);
      }
      if (optimizer) {
        const OptimizerConfig& oc = optimizer->config();
        w.attr(config.get(), "config", "optimizer.kind", to_string(oc.kind));
        w.attr(config.get(), "config", "optimizer.lr", oc.lr);
        w.attr(config.get(), "config", "optimizer.beta1", oc.beta1);
        w.attr(config.get(), "config", "optimizer.beta2", oc.beta2);
        w.attr(config.get(), "config", "optimizer.eps", oc.eps);
        w.attr(config.get(), "config", "optimizer.momentum", oc.momentum);
        w.attr(config.get(), "config", "optimizer.clip_norm", oc.clip_norm);
      }
      for (const auto& [key, value] : meta.attributes) w.attr(config.get(), "config", key, value);
    }
    for (const ParamInfo& info : params.infos())
      w.floats("params/" + info.name, param_dims(info), params.values() + info.offset);
    if (optimizer) {
      Handle opt = w.group("optimizer");
      w.attr(opt.get(), "optimizer", "kind", to_string(optimizer->config().kind));
      w.attr(opt.get(), "optimizer", "steps", optimizer->steps());
      for (const ParamInfo& info : params.infos()) {
        w.floats("optimizer/m/" + info.name, param_dims(info), optimizer->m().data() + info.offset);
        w.floats("optimizer/v/" + info.name, param_dims(info), optimizer->v().data() + info.offset);
      }
    }
    {
      Handle state = w.group("state");
      w.attr(state.get(), "state", "epoch", meta.state.epoch);
      w.attr(state.get(), "state", "step", meta.state.step);
    }
    w.string_dataset("state/rng", meta.state.rng);
    w.close();
  }
}

namespace {

// The file's format number: 1 without the attribute (files written by other tools, e.g. h5py);
// a newer format than this build knows is refused by name.
int format_of(const Reader& r) {
  if (!r.has_attr("config", "format")) return 1;
  const std::string text = r.string_attr("config", "format");
  const std::string prefix = kFormatPrefix;
  int v = 0;
  const char* end = text.data() + text.size();
  const bool number = text.rfind(prefix, 0) == 0 &&
                      std::from_chars(text.data() + prefix.size(), end, v).ptr == end && text.size() > prefix.size();
  if (!number) r.fail("config/format", "\"" + text + "\" is not a lidarsim checkpoint format");
  if (v < 1 || v > kNewestCheckpointFormat)
    r.fail("config/format", "\"" + text + "\": this build reads formats 1 to " + std::to_string(kNewestCheckpointFormat) +
                                (v > kNewestCheckpointFormat ? " (written by a newer lidarsim: update to read it)" : ""));
  return v;
}

// The output channel count and heads: `unet.out_channels` in format 1, `unet.outputs` and the
// optional `unet.heads` in formats 2 to 4; formats 3-4 also `unet.spread_scale` (absent: 1), format
// 4 also `unet.spread_residual` (absent: none).
void outputs_of(const Reader& r, UNetConfig& c) {
  const int format = format_of(r);
  c.out_channels = positive_int_attr(r, format == 1 ? "unet.out_channels" : "unet.outputs");
  c.heads.clear();
  if (r.has_attr("config", "unet.heads")) {
    if (format == 1) r.fail("config/unet.heads", "present in a format-1 checkpoint (format 2 carries heads)");
    const std::string text = r.string_attr("config", "unet.heads");
    try {
      c.heads = parse_heads(text, "value");
      check_heads(c.heads, c.out_channels, "value");
    } catch (const Error& e) {
      r.fail("config/unet.heads", e.what());
    }
  }
  const bool zero_head = head_channel(c.heads, HeadKind::zero_logit) >= 0;
  if (zero_head && format < 5)
    r.fail("config/unet.heads", "a zero_logit head in a format-" + std::to_string(format) + " checkpoint (format 5 carries it)");
  if (format >= 5 && !zero_head) r.fail("config/unet.heads", "format 5, but no zero_logit head");
  c.spread_scale = 1.f;
  if (format >= 3) {
    const double v = r.double_attr("config", "unet.spread_scale");
    const bool spread = has_spread_head(c.heads);
    if (!(v > 0) || !std::isfinite(v) || v > 1e6)
      r.fail("config/unet.spread_scale", "expected a finite number > 0, got " + std::to_string(v));
    if (!spread) r.fail("config/unet.spread_scale", "present, but unet.heads has no spread head");
    c.spread_scale = static_cast<float>(v);
  } else if (r.has_attr("config", "unet.spread_scale")) {
    r.fail("config/unet.spread_scale", "present in a format-" + std::to_string(format) + " checkpoint (format 3 carries it)");
  }
  c.spread_residual = {};
  if (format >= 4) {
    if (!has_spread_head(c.heads)) r.fail("config/unet.spread_residual", "format 4, but unet.heads has no spread head");
    try {
      c.spread_residual = parse_spread_residual(r.string_attr("config", "unet.spread_residual"), "value");
    } catch (const Error& e) {
      r.fail("config/unet.spread_residual", e.what());
    }
  } else if (r.has_attr("config", "unet.spread_residual")) {
    r.fail("config/unet.spread_residual", "present in a format-" + std::to_string(format) + " checkpoint (format 4 carries it)");
  }
}

Checkpoint read_meta(const Reader& r) {
  Checkpoint meta;
  if (!r.exists("config")) r.fail("config", "missing group (not a lidarsim checkpoint?)");
  meta.unet.in_channels = positive_int_attr(r, "unet.in_channels");
  outputs_of(r, meta.unet);
  meta.unet.base = positive_int_attr(r, "unet.base");
  meta.unet.depth = positive_int_attr(r, "unet.depth");
  meta.unet.row_affine_rows = row_affine_rows(r);
  meta.unet.lookup = lookup_config(r);
  for (const std::string& name : r.attr_names("config"))
    if (!reserved_attribute(name)) meta.attributes[name] = r.string_attr("config", name);
  if (r.has_attr("config", "optimizer.kind")) {
    OptimizerConfig oc;
    const std::string kind = r.string_attr("config", "optimizer.kind");
    const auto parsed = optimizer_kind_from_string(kind);
    if (!parsed) r.fail("config/optimizer.kind", "expected \"adam\" or \"sgd\", got \"" + kind + "\"");
    oc.kind = *parsed;
    oc.lr = static_cast<float>(r.double_attr("config", "optimizer.lr"));
    oc.beta1 = static_cast<float>(r.double_attr("config", "optimizer.beta1"));
    oc.beta2 = static_cast<float>(r.double_attr("config", "optimizer.beta2"));
    oc.eps = static_cast<float>(r.double_attr("config", "optimizer.eps"));
    oc.momentum = static_cast<float>(r.double_attr("config", "optimizer.momentum"));
    oc.clip_norm = static_cast<float>(r.double_attr("config", "optimizer.clip_norm"));
    meta.optimizer = oc;
  }
  meta.state.epoch = r.int_attr("state", "epoch");
  meta.state.step = r.int_attr("state", "step");
  meta.state.rng = r.string_dataset("state/rng");
  return meta;
}

void load(const Reader& r, UNet& model, Optimizer* optimizer) {
  const UNetConfig& want = model.config();
  UNetConfig have_outputs;
  outputs_of(r, have_outputs);
  if (have_outputs.out_channels != want.out_channels)
    r.fail(format_of(r) == 1 ? "config/unet.out_channels" : "config/unet.outputs",
           "checkpoint has " + std::to_string(have_outputs.out_channels) + ", the model expects " +
               std::to_string(want.out_channels));
  if (have_outputs.heads != want.heads)
    r.fail("config/unet.heads", "checkpoint has \"" + heads_text(have_outputs.heads) + "\", the model expects \"" +
                                    heads_text(want.heads) + "\"");
  const std::pair<const char*, int> fields[] = {{"unet.in_channels", want.in_channels},
                                                {"unet.base", want.base},
                                                {"unet.depth", want.depth}};
  for (const auto& [name, value] : fields) {
    const std::int64_t have = r.int_attr("config", name);
    if (have != value)
      r.fail(std::string("config/") + name,
             "checkpoint has " + std::to_string(have) + ", the model expects " + std::to_string(value));
  }
  if (const int have = row_affine_rows(r); have != want.row_affine_rows)
    r.fail("config/unet.row_affine_rows", "checkpoint has " + std::to_string(have) + " (0: no per-row affine layer), the model expects " +
                                              std::to_string(want.row_affine_rows));
  if (!(lookup_config(r) == want.lookup))
    r.fail("config/unet.lookup", want.lookup.classes > 0 ? "the lookup base's settings differ from the model's (or it has none)"
                                                         : "checkpoint has a lookup base, the model has none");

  // Validate and read everything first; copy into the model only when all of it is good.
  ParamArena& params = model.params();
  const std::vector<ParamInfo>& infos = params.infos();
  std::vector<std::vector<float>> values, m, v;
  for (const ParamInfo& info : infos) values.push_back(r.floats("params/" + info.name, param_dims(info)));
  for (const std::string& name : r.datasets_below("params"))
    if (params.find(name) < 0) r.fail("params/" + name, "not a parameter of this model");

  std::int64_t steps = 0;
  if (optimizer) {
    if (!r.exists("optimizer")) r.fail("optimizer", "missing group (checkpoint saved without an optimizer)");
    const std::string kind = r.string_attr("optimizer", "kind");
    if (kind != to_string(optimizer->config().kind))
      r.fail("optimizer/kind",
             "checkpoint has \"" + kind + "\", the optimizer is \"" + to_string(optimizer->config().kind) + "\"");
    steps = r.int_attr("optimizer", "steps");
    if (steps < 0) r.fail("optimizer/steps", "expected >= 0, got " + std::to_string(steps));
    if (optimizer->m().size() != params.size() || optimizer->v().size() != params.size())
      r.fail("optimizer", "the optimizer's state size does not match the model");
    for (const ParamInfo& info : infos) {
      m.push_back(r.floats("optimizer/m/" + info.name, param_dims(info)));
      v.push_back(r.floats("optimizer/v/" + info.name, param_dims(info)));
    }
  }

  for (std::size_t i = 0; i < infos.size(); ++i)
    std::copy(values[i].begin(), values[i].end(), params.values() + infos[i].offset);
  if (optimizer) {
    for (std::size_t i = 0; i < infos.size(); ++i) {
      std::copy(m[i].begin(), m[i].end(), optimizer->m().begin() + static_cast<std::ptrdiff_t>(infos[i].offset));
      std::copy(v[i].begin(), v[i].end(), optimizer->v().begin() + static_cast<std::ptrdiff_t>(infos[i].offset));
    }
    optimizer->set_steps(steps);
  }
}

}  // namespace

Checkpoint read_checkpoint_meta(const std::filesystem::path& path) {
  silence_hdf5();
  return read_meta(Reader(path));
}

Checkpoint read_checkpoint_meta(const MemoryImage& image) {
  silence_hdf5();
  return read_meta(Reader(image));
}

void load_checkpoint(const std::filesystem::path& path, UNet& model, Optimizer* optimizer) {
  silence_hdf5();
  load(Reader(path), model, optimizer);
}

void load_checkpoint(const MemoryImage& image, UNet& model, Optimizer* optimizer) {
  silence_hdf5();
  load(Reader(image), model, optimizer);
}

}  // namespace lidarsim::nn
