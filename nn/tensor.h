#pragma once
// Tensor: float32, NCHW, contiguous, 64-byte aligned, owning its storage; shape travels with it.
// Reach Eigen through map(), never by copying.
#include <Eigen/Core>

#include <array>
#include <cstddef>
#include <cstdlib>
#include <memory>
#include <string>
#include <vector>

#include "nn/big_alloc.h"

namespace lidarsim::nn {

struct Shape {
  int n = 0, c = 0, h = 0, w = 0;
  std::size_t numel() const { return static_cast<std::size_t>(n) * c * h * w; }
  std::size_t plane() const { return static_cast<std::size_t>(h) * w; }  // one channel of one image
  std::size_t image() const { return static_cast<std::size_t>(c) * h * w; }  // one image
  bool operator==(const Shape&) const = default;
  std::string str() const {
    return "[" + std::to_string(n) + ", " + std::to_string(c) + ", " + std::to_string(h) + ", " +
           std::to_string(w) + "]";
  }
};

namespace detail {
struct AlignedFree {
  void operator()(float* p) const { std::free(p); }
};
}  // namespace detail

class Tensor {
 public:
  Tensor() = default;
  explicit Tensor(Shape shape) { resize(shape); }
  Tensor(int n, int c, int h, int w) : Tensor(Shape{n, c, h, w}) {}

  Tensor(const Tensor& other) : Tensor(other.shape_) { std::copy(other.begin(), other.end(), begin()); }
  Tensor& operator=(const Tensor& other) {
    if (this != &other) {
      resize(other.shape_);
      std::copy(other.begin(), other.end(), begin());
    }
    return *this;
  }
  Tensor(Tensor&&) noexcept = default;
  Tensor& operator=(Tensor&&) noexcept = default;

  // Reallocates only when the element count grows; contents are zeroed.
  void resize(Shape shape) {
    if (shape.numel() > capacity_) {
      data_.reset(static_cast<float*>(detail::aligned_storage(shape.numel() * sizeof(float))));
      capacity_ = shape.numel();
    }
    shape_ = shape;
    zero();
  }
  void zero() { std::fill(begin(), end(), 0.f); }

  const Shape& shape() const { return shape_; }
  std::size_t numel() const { return shape_.numel(); }
  float* data() { return data_.get(); }
  const float* data() const { return data_.get(); }
  float* begin() { return data_.get(); }
  float* end() { return data_.get() + numel(); }
  const float* begin() const { return data_.get(); }
  const float* end() const { return data_.get() + numel(); }

  float& at(int n, int c, int h, int w) { return data_.get()[index(n, c, h, w)]; }
  float at(int n, int c, int h, int w) const { return data_.get()[index(n, c, h, w)]; }
  float* image(int n) { return data_.get() + static_cast<std::size_t>(n) * shape_.image(); }
  const float* image(int n) const { return data_.get() + static_cast<std::size_t>(n) * shape_.image(); }
  float* channel(int n, int c) { return image(n) + static_cast<std::size_t>(c) * shape_.plane(); }
  const float* channel(int n, int c) const { return image(n) + static_cast<std::size_t>(c) * shape_.plane(); }

  // Flat Eigen view of all elements.
  Eigen::Map<Eigen::VectorXf, Eigen::Aligned64> vec() { return {data(), static_cast<Eigen::Index>(numel())}; }
  Eigen::Map<const Eigen::VectorXf, Eigen::Aligned64> vec() const {
    return {data(), static_cast<Eigen::Index>(numel())};
  }

 private:
  std::size_t index(int n, int c, int h, int w) const {
    return ((static_cast<std::size_t>(n) * shape_.c + c) * shape_.h + h) * shape_.w + w;
  }
  Shape shape_{};
  std::size_t capacity_ = 0;
  std::unique_ptr<float, detail::AlignedFree> data_;
};

}  // namespace lidarsim::nn
