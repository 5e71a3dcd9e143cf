#pragma once
// Naive double-precision reference ops for the engine's tests: an independent implementation
// (plain loops, no im2col, no threads) used both to check our float forward passes and, by
// central differences, our backward passes.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <functional>
#include <random>
#include <string>
#include <vector>

#include "nn/tensor.h"
#include "nn/unet.h"

namespace lidarsim::nn::reference {

struct DT {  // double tensor, NCHW
  Shape s;
  std::vector<double> v;
  DT() = default;
  explicit DT(Shape shape) : s(shape), v(shape.numel(), 0.0) {}
  double& at(int n, int c, int h, int w) { return v[((std::size_t(n) * s.c + c) * s.h + h) * s.w + w]; }
  double at(int n, int c, int h, int w) const { return v[((std::size_t(n) * s.c + c) * s.h + h) * s.w + w]; }
};

inline DT from(const Tensor& t) {
  DT d(t.shape());
  std::copy(t.begin(), t.end(), d.v.begin());
  return d;
}
inline Tensor to_tensor(const DT& d) {
  Tensor t(d.s);
  for (std::size_t i = 0; i < d.v.size(); ++i) t.data()[i] = static_cast<float>(d.v[i]);
  return t;
}

// Uniform values in [-1, 1) from a fixed seed.
inline Tensor random_tensor(Shape s, std::uint64_t seed, float scale = 1.f) {
  std::mt19937_64 rng(seed);
  Tensor t(s);
  for (float& x : t) x = scale * static_cast<float>(static_cast<double>(rng() >> 11) * 0x1.0p-52 - 1.0);
  return t;
}
inline std::vector<float> random_vector(std::size_t n, std::uint64_t seed, float scale = 1.f) {
  Tensor t = random_tensor(Shape{1, 1, 1, static_cast<int>(n)}, seed, scale);
  return std::vector<float>(t.begin(), t.end());
}

// w [co, ci, k, k], b [co] (may be empty)
inline DT conv2d(const DT& in, const std::vector<double>& w, const std::vector<double>& b, int co, int k, int pad,
                 bool relu) {
  const Shape s = in.s;
  DT out(Shape{s.n, co, s.h + 2 * pad - k + 1, s.w + 2 * pad - k + 1});
  for (int n = 0; n < s.n; ++n)
    for (int o = 0; o < co; ++o)
      for (int y = 0; y < out.s.h; ++y)
        for (int x = 0; x < out.s.w; ++x) {
          double acc = b.empty() ? 0.0 : b[o];
          for (int c = 0; c < s.c; ++c)
            for (int kh = 0; kh < k; ++kh)
              for (int kw = 0; kw < k; ++kw) {
                const int iy = y + kh - pad, ix = x + kw - pad;
                if (iy < 0 || iy >= s.h || ix < 0 || ix >= s.w) continue;
                acc += w[((std::size_t(o) * s.c + c) * k + kh) * k + kw] * in.at(n, c, iy, ix);
              }
          out.at(n, o, y, x) = relu ? std::max(acc, 0.0) : acc;
        }
  return out;
}

// w [ci, co, 2, 2]; output zero-padded to out_h x out_w
inline DT conv_transpose2x2(const DT& in, const std::vector<double>& w, const std::vector<double>& b, int co,
                            int out_h, int out_w) {
  const Shape s = in.s;
  DT out(Shape{s.n, co, out_h, out_w});
  for (int n = 0; n < s.n; ++n)
    for (int o = 0; o < co; ++o)
      for (int y = 0; y < 2 * s.h; ++y)
        for (int x = 0; x < 2 * s.w; ++x) {
          double acc = b.empty() ? 0.0 : b[o];
          for (int c = 0; c < s.c; ++c)
            acc += in.at(n, c, y / 2, x / 2) * w[((std::size_t(c) * co + o) * 2 + y % 2) * 2 + x % 2];
          out.at(n, o, y, x) = acc;
        }
  return out;
}

inline DT max_pool2x2(const DT& in) {
  const Shape s = in.s;
  DT out(Shape{s.n, s.c, s.h / 2, s.w / 2});
  for (int n = 0; n < s.n; ++n)
    for (int c = 0; c < s.c; ++c)
      for (int y = 0; y < out.s.h; ++y)
        for (int x = 0; x < out.s.w; ++x)
          out.at(n, c, y, x) = std::max(std::max(in.at(n, c, 2 * y, 2 * x), in.at(n, c, 2 * y, 2 * x + 1)),
                                        std::max(in.at(n, c, 2 * y + 1, 2 * x), in.at(n, c, 2 * y + 1, 2 * x + 1)));
  return out;
}

inline DT relu(const DT& in) {
  DT out = in;
  for (double& x : out.v) x = std::max(x, 0.0);
  return out;
}

inline DT concat(const DT& a, const DT& b) {
  DT out(Shape{a.s.n, a.s.c + b.s.c, a.s.h, a.s.w});
  for (int n = 0; n < a.s.n; ++n) {
    std::copy(a.v.begin() + n * a.s.image(), a.v.begin() + (n + 1) * a.s.image(), out.v.begin() + n * out.s.image());
    std::copy(b.v.begin() + n * b.s.image(), b.v.begin() + (n + 1) * b.s.image(),
              out.v.begin() + n * out.s.image() + a.s.image());
  }
  return out;
}

// The lookup base of nn/layers.h, written from its comment: [N, 1, H, W].
inline DT lookup_base(const DT& x, const LookupBaseConfig& c, const std::vector<double>& table,
                      const std::vector<double>& beam) {
  DT out(Shape{x.s.n, 1, x.s.h, x.s.w});
  for (int n = 0; n < x.s.n; ++n)
    for (int h = 0; h < x.s.h; ++h)
      for (int w = 0; w < x.s.w; ++w) {
        const double r = x.at(n, c.range_channel, h, w);
        if (!(r > 0)) continue;
        int g = c.classes;
        for (int j = c.classes - 1; j >= 0; --j)
          if (x.at(n, c.class_channel + j, h, w) > 0.5) g = j;
        const int b = std::clamp(static_cast<int>(std::floor(static_cast<float>(r) / c.bin_width)), 0, c.range_bins - 1);
        out.at(n, 0, h, w) = table[std::size_t(g) * c.range_bins + b] + beam[h];
      }
  return out;
}

// The UNet of nn/unet.h, written from its comment, over a double copy of the arena's values.
inline DT unet(const UNet& model, const std::vector<double>& p, const DT& x) {
  const UNetConfig& cfg = model.config();
  const ParamArena& arena = model.params();
  auto get = [&](const std::string& name) {
    const int id = arena.find(name);
    const ParamInfo& info = arena.info(id);
    return std::vector<double>(p.begin() + info.offset, p.begin() + info.offset + info.shape.numel());
  };
  auto conv = [&](const DT& in, const std::string& layer, int k, int pad, bool act) {
    const int id = arena.find(layer + "/weight");
    return conv2d(in, get(layer + "/weight"), get(layer + "/bias"), arena.info(id).shape.n, k, pad, act);
  };
  std::vector<DT> skips;
  DT cur = x, base;
  if (cfg.lookup.classes > 0) {
    base = lookup_base(x, cfg.lookup, get("lookup/table"), get("lookup/beam"));
    cur = concat(x, base);
  }
  for (int l = 0; l <= cfg.depth; ++l) {
    if (l > 0) cur = max_pool2x2(skips.back());
    const std::string e = "enc" + std::to_string(l);
    cur = conv(conv(cur, e + ".conv1", 3, 1, true), e + ".conv2", 3, 1, true);
    skips.push_back(cur);
  }
  for (int l = cfg.depth - 1; l >= 0; --l) {
    const std::string d = "dec" + std::to_string(l);
    const DT& skip = skips[l];
    const int c = skip.s.c;
    DT up = conv_transpose2x2(cur, get(d + ".up/weight"), get(d + ".up/bias"), c, skip.s.h, skip.s.w);
    cur = conv(conv(concat(skip, up), d + ".conv1", 3, 1, true), d + ".conv2", 3, 1, true);
  }
  DT y = conv(cur, "head", 1, 0, false);
  if (cfg.row_affine_rows > 0) {
    const std::vector<double> gain = get("row_affine/gain"), offset = get("row_affine/offset");
    for (int n = 0; n < y.s.n; ++n)
      for (int c = 0; c < y.s.c; ++c)
        for (int h = 0; h < y.s.h; ++h)
          for (int w = 0; w < y.s.w; ++w) {
            double& v = y.v[((std::size_t(n) * y.s.c + c) * y.s.h + h) * y.s.w + w];
            v = gain[std::size_t(c) * y.s.h + h] * v + offset[std::size_t(c) * y.s.h + h];
          }
  }
  if (cfg.lookup.classes > 0)  // onto channel 0 (the mean head)
    for (int n = 0; n < y.s.n; ++n)
      for (int h = 0; h < y.s.h; ++h)
        for (int w = 0; w < y.s.w; ++w) y.at(n, 0, h, w) += base.at(n, 0, h, w);
  return y;
}

inline double dot(const DT& a, const std::vector<double>& r) {
  double s = 0;
  for (std::size_t i = 0; i < a.v.size(); ++i) s += a.v[i] * r[i];
  return s;
}

// Central difference of f at x (perturbing x[i] by +-eps in double).
inline std::vector<double> numeric_gradient(std::vector<double>& x, const std::function<double()>& f,
                                            double eps = 1e-6) {
  std::vector<double> g(x.size());
  for (std::size_t i = 0; i < x.size(); ++i) {
    const double keep = x[i];
    x[i] = keep + eps;
    const double fp = f();
    x[i] = keep - eps;
    const double fm = f();
    x[i] = keep;
    g[i] = (fp - fm) / (2 * eps);
  }
  return g;
}

// max |analytic - numeric| / max |numeric|: scale-free, and one wrong entry shows as a large value.
inline double max_rel_error(const float* analytic, const std::vector<double>& numeric) {
  double err = 0, scale = 1e-12;
  for (std::size_t i = 0; i < numeric.size(); ++i) {
    err = std::max(err, std::abs(static_cast<double>(analytic[i]) - numeric[i]));
    scale = std::max(scale, std::abs(numeric[i]));
  }
  return err / scale;
}

}  // namespace lidarsim::nn::reference
