#pragma once
// Where the real measured data live for tests: $LIDARSIM_SHARED_DATA, else ../shared/data
// beside the checkout. On a user's clone without it the test skips with a message; when CI is
// set a missing folder is a failure, so a wrong path can never pass silently.
#include <gtest/gtest.h>

#include <cstdlib>
#include <filesystem>
#include <string>

namespace lidarsim::testing {

inline std::filesystem::path shared_data_root() {
  if (const char* env = std::getenv("LIDARSIM_SHARED_DATA")) return env;
  return LIDARSIM_SHARED_DATA_DEFAULT;
}

inline bool running_in_ci() {
  const char* ci = std::getenv("CI");
  return ci && *ci && std::string(ci) != "0" && std::string(ci) != "false";
}

inline std::filesystem::path source_dir() { return LIDARSIM_SOURCE_DIR; }
inline std::filesystem::path binary_dir() { return LIDARSIM_BINARY_DIR; }

}  // namespace lidarsim::testing

// Sets `var` to shared_data_root()/sub, or skips (fails under CI) when it is missing.
#define LIDARSIM_REQUIRE_SHARED_DATA(var, sub)                                                        \
  const std::filesystem::path var = ::lidarsim::testing::shared_data_root() / (sub);                 \
  do {                                                                                               \
    if (!std::filesystem::exists(var)) {                                                             \
      if (::lidarsim::testing::running_in_ci())                                                      \
        FAIL() << "CI is set but the measured data are missing: " << var;                           \
      GTEST_SKIP() << "measured data not found at " << var                                           \
                   << " (a clone without ../shared; set LIDARSIM_SHARED_DATA to run this test)";   \
    }                                                                                                \
  } while (0)
