#pragma once
// Forces the 3x3 convolutions onto one algorithm (direct or Winograd) for a test's scope, so the
// same checks run on every path whatever the automatic rule would pick for the test's sizes.
#include "nn/conv3x3.h"

namespace lidarsim::nn::conv_paths {

struct Conv3x3PathGuard {
  explicit Conv3x3PathGuard(detail::Conv3x3Path path) : old(detail::conv3x3_path()) {
    detail::set_conv3x3_path(path);
  }
  ~Conv3x3PathGuard() { detail::set_conv3x3_path(old); }
  Conv3x3PathGuard(const Conv3x3PathGuard&) = delete;
  Conv3x3PathGuard& operator=(const Conv3x3PathGuard&) = delete;
  detail::Conv3x3Path old;
};

inline const char* path_name(detail::Conv3x3Path p) {
  return p == detail::Conv3x3Path::direct ? "direct" : p == detail::Conv3x3Path::winograd ? "winograd" : "auto";
}

}  // namespace lidarsim::nn::conv_paths
