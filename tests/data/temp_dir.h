#pragma once
// A fresh temporary folder per test, removed afterwards.
#include <gtest/gtest.h>
#include <unistd.h>

#include "common/error.h"

#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

namespace lidarsim::testing {

class TempDir {
 public:
  TempDir() {
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    path_ = std::filesystem::temp_directory_path() /
            ("lidarsim_" + std::string(info->test_suite_name()) + "_" + info->name() + "_" + std::to_string(::getpid()));
    std::filesystem::remove_all(path_);
    std::filesystem::create_directories(path_);
  }
  ~TempDir() { std::filesystem::remove_all(path_); }
  const std::filesystem::path& path() const { return path_; }
  std::filesystem::path operator/(const std::string& s) const { return path_ / s; }

 private:
  std::filesystem::path path_;
};

template <typename T>
inline void write_binary(const std::filesystem::path& p, const std::vector<T>& values, std::size_t extra_bytes = 0) {
  std::filesystem::create_directories(p.parent_path());
  std::ofstream out(p, std::ios::binary);
  out.write(reinterpret_cast<const char*>(values.data()), static_cast<std::streamsize>(values.size() * sizeof(T)));
  for (std::size_t i = 0; i < extra_bytes; ++i) out.put('\0');
}

// The message of the lidarsim::Error `f` throws, or "" when it throws none.
inline std::string error_of(auto&& f) {
  try {
    f();
  } catch (const lidarsim::Error& e) {
    return e.what();
  }
  return "";
}

}  // namespace lidarsim::testing
