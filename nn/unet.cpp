#include "nn/unet.h"

#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <map>
#include <random>
#include <vector>

#include "common/error.h"
#include "nn/layers.h"
#include "nn/parallel.h"
#include "nn/precision.h"
#include "nn/weight_cache.h"

namespace lidarsim::nn {

namespace {

int channels(const UNetConfig& c, int level) { return c.base << level; }

// Ids of one conv's parameters in the arena.
struct ConvIds {
  int w = -1, b = -1;
};

}  // namespace

struct UNet::Workspace {
  struct Level {
    int h = 0, w = 0;
    // Encoder: a1 [N, c, h, w] = relu(conv1), a2 [N, c, h, w] = relu(conv2) (the skip);
    // pool [N, c, h/2, w/2] with argmax (levels < depth).
    Tensor a1, a2, pool;
    std::vector<std::int32_t> argmax;
    // Decoder (levels < depth): up [N, c, h, w] (padded transposed conv of the level below),
    // d1 = relu(conv1([skip, up])) (the concat is never materialised), d2 [N, c, h, w].
    Tensor up, d1, d2;
    // Gradients of the tensors above, same shapes.
    Tensor g_a1, g_a2, g_pool, g_up, g_d1, g_d2;
  };
  std::vector<Level> levels;
  Tensor x;  // [N, in, H, W] copy of the last forward's input (enc0.conv1's weight gradient)
  Tensor y;  // [N, out, H, W] the last forward's output
  Tensor head_out, g_head_out;  // the head's output before the row affine, and its gradient
  int gain = -1, offset = -1;  // row-affine parameters (-1: none)
  int table = -1, beam = -1;   // lookup-base parameters (-1: none)
  Tensor base;                 // [N, 1, H, W] the lookup base of the last forward
  bool have_forward = false;
  detail::ConvSettings conv;          // of the call that runs (conv_settings)
  detail::WeightCache weight_cache;  // packed conv weights, kept across predict() calls
  std::vector<ConvIds> enc1, enc2, up, dec1, dec2;
  ConvIds head;

  // LIDARSIM_PROFILE=1: wall time per layer and pass, printed to stderr when the model goes;
  // LIDARSIM_PROFILE=cpu: process CPU time instead (steadier on a loaded machine, one thread). Both
  // leave out the first forward and backward pass, whose buffers are new.
  const char* profile_env = std::getenv("LIDARSIM_PROFILE");
  bool profile = profile_env != nullptr;
  bool profile_cpu = profile && std::string(profile_env) == "cpu";
  std::map<std::string, double> seconds;
  int forwards = 0;  // the first forward and backward allocate (page faults): left out of the profile
  double t0 = 0;
  double now() const {
    if (profile_cpu) {
      timespec t;
      clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t);
      return t.tv_sec + 1e-9 * t.tv_nsec;
    }
    return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
  }
  void tic() {
    if (profile) t0 = now();
  }
  void toc(const std::string& what) {
    if (profile && forwards > 1) seconds[what] += now() - t0;
  }
  ~Workspace() {
    if (!profile || seconds.empty()) return;
    double total = 0;
    for (const auto& [k, v] : seconds) total += v;
    for (const auto& [k, v] : seconds) std::fprintf(stderr, "profile %-22s %8.4f s %5.1f %%\n", k.c_str(), v, 100 * v / total);
  }
};

UNet::UNet(const UNetConfig& config) : config_(config), ws_(std::make_unique<Workspace>()) {
  const auto bad = [](const std::string& field, int v, const std::string& expected) {
    return Error("UNet config: " + field + ": expected " + expected + ", got " + std::to_string(v));
  };
  if (config.in_channels < 1) throw bad("in_channels", config.in_channels, ">= 1");
  if (config.out_channels < 1) throw bad("out_channels", config.out_channels, ">= 1");
  if (config.base < 1) throw bad("base", config.base, ">= 1");
  if (config.depth < 0 || config.depth > 10) throw bad("depth", config.depth, "0..10");
  if (config.row_affine_rows < 0 || config.row_affine_rows > 1 << 16)
    throw bad("row_affine_rows", config.row_affine_rows, "0 (none) .. 65536");
  const LookupBaseConfig& lk = config.lookup;
  if (lk.classes < 0) throw bad("lookup.classes", lk.classes, ">= 0 (0: none)");
  if (lk.classes > 0) {
    if (lk.class_channel < 0 || lk.class_channel + lk.classes > config.in_channels)
      throw bad("lookup.class_channel", lk.class_channel, "classes one-hot channels inside the input");
    if (lk.range_channel < 0 || lk.range_channel >= config.in_channels)
      throw bad("lookup.range_channel", lk.range_channel, "an input channel");
    if (lk.range_bins < 1 || lk.range_bins > 1 << 16) throw bad("lookup.range_bins", lk.range_bins, "1 .. 65536");
    if (lk.rows < 1 || lk.rows > 1 << 16) throw bad("lookup.rows", lk.rows, "1 .. 65536");
    if (!(lk.bin_width > 0) || !std::isfinite(lk.bin_width))
      throw Error("UNet config: lookup.bin_width: expected a finite number > 0, got " + std::to_string(lk.bin_width));
  }
  check_heads(config.heads, config.out_channels, "UNet config: heads");
  if (!(config.spread_scale > 0) || !std::isfinite(config.spread_scale))
    throw Error("UNet config: spread_scale: expected a finite number > 0, got " + std::to_string(config.spread_scale));
  if (config.spread_scale != 1.f && !has_spread_head(config.heads))
    throw Error("UNet config: spread_scale: " + std::to_string(config.spread_scale) + " without a spread head");
  check_spread_residual(config.spread_residual, "UNet config: spread_residual");
  if (!config.spread_residual.empty() && !has_spread_head(config.heads))
    throw Error("UNet config: spread_residual: a residual table without a spread head");
  const int in_net = config.in_channels + (lk.classes > 0 ? 1 : 0);  // enc0.conv1 also sees the base

  auto conv = [&](const std::string& name, int out, int in, int k) {
    ConvIds ids;
    ids.w = params_.add(name + "/weight", Shape{out, in, k, k}, true);
    ids.b = params_.add(name + "/bias", Shape{out, 1, 1, 1}, false);
    return ids;
  };
  Workspace& ws = *ws_;
  ws.levels.resize(static_cast<std::size_t>(config.depth) + 1);
  for (int l = 0; l <= config.depth; ++l) {
    const int c = channels(config, l), cin = l == 0 ? in_net : channels(config, l - 1);
    ws.enc1.push_back(conv("enc" + std::to_string(l) + ".conv1", c, cin, 3));
    ws.enc2.push_back(conv("enc" + std::to_string(l) + ".conv2", c, c, 3));
  }
  ws.up.resize(static_cast<std::size_t>(config.depth));
  ws.dec1.resize(static_cast<std::size_t>(config.depth));
  ws.dec2.resize(static_cast<std::size_t>(config.depth));
  for (int l = config.depth - 1; l >= 0; --l) {
    const int c = channels(config, l);
    const std::string p = "dec" + std::to_string(l);
    ConvIds up;
    up.w = params_.add(p + ".up/weight", Shape{2 * c, c, 2, 2}, true);  // [in, out, 2, 2]
    up.b = params_.add(p + ".up/bias", Shape{c, 1, 1, 1}, false);
    ws.up[l] = up;
    ws.dec1[l] = conv(p + ".conv1", c, 2 * c, 3);
    ws.dec2[l] = conv(p + ".conv2", c, c, 3);
  }
  ws.head = conv("head", config.out_channels, channels(config, 0), 1);
  if (config.row_affine_rows > 0) {
    // Steps 10x the learning rate: Adam moves each parameter by about lr per step, and a laser's
    // gain may sit 0.4 from 1 (0.6..1.4 on the reference sensor), beyond what a short run at
    // lr 2e-3 can travel; the network's weights need no such distance.
    const Shape s{1, config.out_channels, config.row_affine_rows, 1};
    ws.gain = params_.add("row_affine/gain", s, true, 1.f, 10.f);
    ws.offset = params_.add("row_affine/offset", s, true, 0.f, 10.f);
  }
  if (lk.classes > 0) {  // fitted, not trained: no decay, step 0
    ws.table = params_.add("lookup/table", Shape{1, 1, lk.classes + 1, lk.range_bins}, false, 0.f, 0.f);
    ws.beam = params_.add("lookup/beam", Shape{1, 1, lk.rows, 1}, false, 0.f, 0.f);
  }
  params_.finalize();
}

void UNet::set_spread_scale(float factor) {
  if (!(factor > 0) || !std::isfinite(factor))
    throw Error("UNet::set_spread_scale: expected a finite number > 0, got " + std::to_string(factor));
  if (factor != 1.f && !has_spread_head(config_.heads)) throw Error("UNet::set_spread_scale: the model has no spread head");
  config_.spread_scale = factor;
}

void UNet::set_spread_residual(SpreadResidual residual) {
  check_spread_residual(residual, "UNet::set_spread_residual");
  if (!residual.empty() && !has_spread_head(config_.heads))
    throw Error("UNet::set_spread_residual: the model has no spread head");
  config_.spread_residual = std::move(residual);
}

UNet::~UNet() = default;
UNet::UNet(UNet&&) noexcept = default;
UNet& UNet::operator=(UNet&&) noexcept = default;

void UNet::init(std::uint64_t seed) {
  // He-normal from std::mt19937_64 through our own Box-Muller, so the weights do not depend on
  // the standard library's distribution code. Transposed convs: each output sums `in` terms.
  std::mt19937_64 rng(seed);
  const auto uniform = [&rng]() { return static_cast<double>(rng() >> 11) * 0x1.0p-53; };  // [0, 1)
  for (const ParamInfo& p : params_.infos()) {
    float* v = params_.values() + p.offset;
    const std::size_t n = p.shape.numel();
    if (p.name.rfind("row_affine/", 0) == 0) {  // identity: gain 1, offset 0
      std::fill(v, v + n, p.decay_center);
      continue;
    }
    // Biases, the lookup table (fitted later) and, with a lookup base, the head start at 0: the
    // untrained model then predicts the table exactly.
    if (!p.decays || (config_.lookup.classes > 0 && p.name.rfind("head/", 0) == 0)) {
      std::fill(v, v + n, 0.f);
      continue;
    }
    const bool transposed = p.name.find(".up/") != std::string::npos;
    const double fan_in = transposed ? p.shape.n : static_cast<double>(p.shape.c) * p.shape.h * p.shape.w;
    const double stddev = std::sqrt(2.0 / fan_in);
    for (std::size_t i = 0; i < n; i += 2) {
      const double u1 = 1.0 - uniform();  // (0, 1]: log stays finite
      const double u2 = uniform();
      const double r = std::sqrt(-2.0 * std::log(u1));
      v[i] = static_cast<float>(stddev * r * std::cos(2.0 * M_PI * u2));
      if (i + 1 < n) v[i + 1] = static_cast<float>(stddev * r * std::sin(2.0 * M_PI * u2));
    }
  }
  params_.zero_grads();
}

void UNet::forward(const Tensor& x, Tensor& y) { run_forward(x, y, conv_settings(false)); }

void UNet::run_forward(const Tensor& x, Tensor& y, const detail::ConvSettings& cs) {
  ws_->conv = cs;
  ++ws_->forwards;
  check_input(x.shape());
  take_input(x);
  const Tensor& below = forward_decoder(forward_encoder());
  forward_head(below, y);
  ws_->have_forward = true;
}

void UNet::check_input(const Shape& s) const {
  const int min_size = 1 << config_.depth;
  if (s.c != config_.in_channels)
    throw Error("UNet forward: input: expected " + std::to_string(config_.in_channels) + " channels, got shape " +
                s.str());
  if (s.n < 1 || s.h < min_size || s.w < min_size)
    throw Error("UNet forward: input: expected N >= 1 and H, W >= " + std::to_string(min_size) + " (2^depth), got " +
                s.str());
  if (config_.row_affine_rows > 0 && s.h != config_.row_affine_rows)
    throw Error("UNet forward: input: the row-affine layer has " + std::to_string(config_.row_affine_rows) +
                " rows (one per laser), got shape " + s.str());
  if (config_.lookup.classes > 0 && s.h != config_.lookup.rows)
    throw Error("UNet forward: input: the lookup base has " + std::to_string(config_.lookup.rows) +
                " rows (one beam offset per laser), got shape " + s.str());
}

// The network's input in the workspace: x checked for non-finite values and copied, or, with a
// lookup base, [x, base].
void UNet::take_input(const Tensor& x) {
  const Shape s = x.shape();
  Workspace& ws = *ws_;
  // The check (and the copy, without a lookup base) in parallel: at batch 4 they are 3 MB each.
  const bool copy = ws_->table < 0;
  if (copy && !(ws.x.shape() == s)) ws.x.resize(s);
  std::atomic<bool> finite{true};
  detail::parallel_ranges(static_cast<long>(x.numel()), x.numel() > (1u << 15), [&](long b, long e) {
    const float* src = x.data();
    bool ok = true;
    for (long i = b; i < e; ++i) ok &= std::isfinite(src[i]);
    if (copy) std::copy(src + b, src + e, ws.x.data() + b);
    if (!ok) finite = false;
  });
  if (!finite) {
    ws.have_forward = false;  // the copy no longer matches the activations
    for (std::size_t i = 0; i < x.numel(); ++i)
      if (!std::isfinite(x.data()[i]))
        throw Error("UNet forward: input: non-finite value at flat index " + std::to_string(i));
  }

  const float* pv = params_.values();
  const auto W = [&](int id) { return pv + params_.info(id).offset; };
  if (ws.table >= 0) {  // the network's input is [x, base]
    ws.tic();
    lookup_base_forward(ws.base, x, config_.lookup, W(ws.table), W(ws.beam));
    ws.x.resize({s.n, s.c + 1, s.h, s.w});
    const std::size_t plane = static_cast<std::size_t>(s.h) * s.w;
    for (int n = 0; n < s.n; ++n) {
      std::copy(x.image(n), x.image(n) + s.c * plane, ws.x.image(n));
      std::copy(ws.base.image(n), ws.base.image(n) + plane, ws.x.channel(n, s.c));
    }
    ws.toc("fwd lookup");
  }
}

// Encoder: two 3x3 convolutions per level, a 2x2 max pool between levels; returns the deepest
// level's output.
const Tensor& UNet::forward_encoder() {
  Workspace& ws = *ws_;
  const float* pv = params_.values();
  const auto W = [&](int id) { return pv + params_.info(id).offset; };
  const int depth = config_.depth;
  const Tensor* cur = &ws.x;
  for (int l = 0; l <= depth; ++l) {
    auto& L = ws.levels[l];
    if (l > 0) {
      auto& P = ws.levels[l - 1];
      ws.tic();
      max_pool2x2_forward(P.pool, P.argmax, P.a2);
      ws.toc("fwd pool");
      cur = &P.pool;
    }
    L.h = cur->shape().h;
    L.w = cur->shape().w;
    const int c = channels(config_, l);
    ws.tic();
    conv2d_forward(L.a1, *cur, W(ws.enc1[l].w), W(ws.enc1[l].b), c, 3, 1, true, ws.conv);
    ws.toc("fwd enc" + std::to_string(l) + ".conv1");
    ws.tic();
    conv2d_forward(L.a2, L.a1, W(ws.enc2[l].w), W(ws.enc2[l].b), c, 3, 1, true, ws.conv);
    ws.toc("fwd enc" + std::to_string(l) + ".conv2");
  }
  return ws.levels[depth].a2;
}

// Decoder: per level up-convolution, a 3x3 convolution on [skip, up] and another 3x3.
const Tensor& UNet::forward_decoder(const Tensor& deepest) {
  Workspace& ws = *ws_;
  const float* pv = params_.values();
  const auto W = [&](int id) { return pv + params_.info(id).offset; };
  const int depth = config_.depth;
  const Tensor* below = &deepest;
  for (int l = depth - 1; l >= 0; --l) {
    auto& L = ws.levels[l];
    const int c = channels(config_, l);
    const std::string d = "dec" + std::to_string(l);
    ws.tic();
    conv_transpose2x2_forward(L.up, *below, W(ws.up[l].w), W(ws.up[l].b), c, L.h, L.w);
    ws.toc("fwd " + d + ".up");
    ws.tic();
    conv2d_cat_forward(L.d1, L.a2, L.up, W(ws.dec1[l].w), W(ws.dec1[l].b), c, true, ws.conv);  // on [skip, up]
    ws.toc("fwd " + d + ".conv1");
    ws.tic();
    conv2d_forward(L.d2, L.d1, W(ws.dec2[l].w), W(ws.dec2[l].b), c, 3, 1, true, ws.conv);
    ws.toc("fwd " + d + ".conv2");
    below = &L.d2;
  }
  return *below;
}

// The 1x1 head (then the row affine, when the model has it) and the lookup base added back.
void UNet::forward_head(const Tensor& below, Tensor& y) {
  Workspace& ws = *ws_;
  const float* pv = params_.values();
  const auto W = [&](int id) { return pv + params_.info(id).offset; };
  ws.tic();
  if (ws.gain >= 0) {
    conv2d_forward(ws.head_out, below, W(ws.head.w), W(ws.head.b), config_.out_channels, 1, 0, false, ws.conv);
    ws.toc("fwd head");
    ws.tic();
    row_affine_forward(y, ws.head_out, W(ws.gain), W(ws.offset));
    ws.toc("fwd row_affine");
  } else {
    conv2d_forward(y, below, W(ws.head.w), W(ws.head.b), config_.out_channels, 1, 0, false, ws.conv);
    ws.toc("fwd head");
  }
  if (ws.table >= 0) {  // onto channel 0, the mean
    const Shape s = y.shape();
    for (int n = 0; n < s.n; ++n) {
      float* out = y.channel(n, 0);
      const float* base = ws.base.image(n);
      for (std::size_t i = 0; i < s.plane(); ++i) out[i] += base[i];
    }
  }
}

detail::ConvSettings UNet::conv_settings(bool inference) const {
  detail::ConvSettings cs;
  cs.conv3x3 = has_conv3x3_ ? conv3x3_ : detail::conv3x3_path();
  cs.plan = plan_.get();
  if (inference) {
    const InferencePrecision p = has_precision_ ? precision_ : inference_precision();
    cs.bf16 = effective_inference_precision(p) == InferencePrecision::bf16;
    cs.weight_cache = &ws_->weight_cache;
  }
  return cs;
}

void UNet::predict(const Tensor& x, Tensor& y) {
  // The graph keeps every activation anyway (they are reused buffers), so inference is forward()
  // with the inference settings (bf16 when that precision is on, packed weights kept).
  run_forward(x, y, conv_settings(true));
}

void UNet::backward(const Tensor& dy) {
  Workspace& ws = *ws_;
  const detail::ConvSettings cs = conv_settings(false);
  if (!ws.have_forward) throw Error("UNet backward: called before forward()");
  const int depth = config_.depth;
  // The added base passes dy through unchanged; its table is fitted, not trained (no gradient).
  const Shape expect{ws.x.shape().n, config_.out_channels, ws.x.shape().h, ws.x.shape().w};
  if (!(dy.shape() == expect))
    throw Error("UNet backward: dy: expected shape " + expect.str() + ", got " + dy.shape().str());
  const float* pv = params_.values();
  float* pg = params_.grads();
  const auto W = [&](int id) { return pv + params_.info(id).offset; };
  const auto G = [&](int id) { return pg + params_.info(id).offset; };

  // Row affine, then the head (1x1, no activation): its "out" is unused without ReLU.
  const Tensor* g_head = &dy;
  if (ws.gain >= 0) {
    ws.tic();
    row_affine_backward(ws.g_head_out, G(ws.gain), G(ws.offset), dy, ws.head_out, W(ws.gain));
    ws.toc("bwd row_affine");
    g_head = &ws.g_head_out;
  }
  {
    const Tensor& top = depth > 0 ? ws.levels[0].d2 : ws.levels[0].a2;
    Tensor& g_top = depth > 0 ? ws.levels[0].g_d2 : ws.levels[0].g_a2;
    ws.tic();
    conv2d_backward(&g_top, G(ws.head.w), G(ws.head.b), *g_head, *g_head, top, W(ws.head.w), 1, 0, false, cs);
    ws.toc("bwd head");
  }
  for (int l = 0; l < depth; ++l) {
    auto& L = ws.levels[l];
    auto& B = ws.levels[l + 1];
    const std::string d = "dec" + std::to_string(l);
    ws.tic();
    conv2d_backward(&L.g_d1, G(ws.dec2[l].w), G(ws.dec2[l].b), L.g_d2, L.d2, L.d1, W(ws.dec2[l].w), 3, 1, true, cs);
    ws.toc("bwd " + d + ".conv2");
    ws.tic();
    conv2d_cat_backward(L.g_a2, L.g_up, G(ws.dec1[l].w), G(ws.dec1[l].b), L.g_d1, L.d1, L.a2, L.up, W(ws.dec1[l].w),
                        true, cs);
    ws.toc("bwd " + d + ".conv1");
    const bool bottom = l + 1 == depth;
    ws.tic();
    conv_transpose2x2_backward(bottom ? B.g_a2 : B.g_d2, G(ws.up[l].w), G(ws.up[l].b), L.g_up,
                               bottom ? B.a2 : B.d2, W(ws.up[l].w));
    ws.toc("bwd " + d + ".up");
  }
  for (int l = depth; l >= 0; --l) {
    auto& L = ws.levels[l];
    const std::string e = "enc" + std::to_string(l);
    ws.tic();
    conv2d_backward(&L.g_a1, G(ws.enc2[l].w), G(ws.enc2[l].b), L.g_a2, L.a2, L.a1, W(ws.enc2[l].w), 3, 1, true, cs);
    ws.toc("bwd " + e + ".conv2");
    ws.tic();
    if (l > 0) {
      auto& P = ws.levels[l - 1];
      conv2d_backward(&P.g_pool, G(ws.enc1[l].w), G(ws.enc1[l].b), L.g_a1, L.a1, P.pool, W(ws.enc1[l].w), 3, 1,
                      true, cs);
      ws.toc("bwd " + e + ".conv1");
      ws.tic();
      max_pool2x2_backward(P.g_a2, P.g_pool, P.argmax, P.a2.shape(), true);
      ws.toc("bwd pool");
    } else {
      conv2d_backward(nullptr, G(ws.enc1[l].w), G(ws.enc1[l].b), L.g_a1, L.a1, ws.x, W(ws.enc1[l].w), 3, 1, true, cs);
      ws.toc("bwd " + e + ".conv1");
    }
  }
}

double UNet::forward_flops(int n, int h, int w) const {
  double macs = 0;
  std::vector<double> hw;
  for (int l = 0, hh = h, ww = w; l <= config_.depth; ++l, hh /= 2, ww /= 2) hw.push_back(double(hh) * ww);
  for (int l = 0; l <= config_.depth; ++l) {
    const double c = channels(config_, l),
                 cin = l == 0 ? config_.in_channels + (config_.lookup.classes > 0 ? 1 : 0) : channels(config_, l - 1);
    macs += (cin * c + c * c) * 9 * hw[l];
  }
  for (int l = 0; l < config_.depth; ++l) {
    const double c = channels(config_, l);
    macs += 2 * c * c * 4 * hw[l + 1];      // transposed conv
    macs += (2 * c * c + c * c) * 9 * hw[l];  // conv1, conv2
  }
  macs += double(channels(config_, 0)) * config_.out_channels * hw[0];
  if (config_.row_affine_rows > 0) macs += double(config_.out_channels) * hw[0];
  if (config_.lookup.classes > 0) macs += hw[0];  // the added base
  return 2.0 * macs * n;
}

}  // namespace lidarsim::nn
