#pragma once
// A checkpoint whose every output is its head's bias: the mean and a Laplace scale, the same at
// every cell (the weights 0), so a test knows its spread exactly. Inputs: range, class, material.
#include <algorithm>
#include <cmath>
#include <filesystem>
#include <string>

#include "nn/checkpoint.h"
#include "nn/heads.h"
#include "nn/unet.h"
#include "pgm/encoder.h"
#include "tests/support/temp_path.h"

namespace lidarsim::testing {

inline std::filesystem::path constant_spread_checkpoint(const std::string& name, float mean, float laplace_scale) {
  const std::filesystem::path dir = temp_path(name);
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  pgm::EncoderConfig encoder;
  encoder.channels = {"range", "class", "material"};
  nn::UNetConfig config{encoder.input_channels(), 2, 4, 2, 0};
  config.heads = {nn::HeadKind::mean, nn::HeadKind::log_scale_laplace};
  nn::UNet model(config);
  std::fill(model.params().values(), model.params().values() + model.params().size(), 0.f);
  float* bias = model.params().value(model.params().find("head/bias"));
  bias[0] = mean, bias[1] = std::log(laplace_scale);
  nn::Checkpoint meta;
  meta.attributes["encoder"] = encoder.to_json();
  nn::save_checkpoint(dir / "ck.h5", model, nullptr, meta);
  return dir / "ck.h5";
}

}  // namespace lidarsim::testing
