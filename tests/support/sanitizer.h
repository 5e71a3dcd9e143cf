#pragma once
// The suite also runs built with AddressSanitizer + UndefinedBehaviorSanitizer (scripts/test.sh,
// build-asan/), where code runs 3-10x slower. Tests that train a UNet for many steps take a
// lighter setting there (fewer steps, same checks on the code paths); each says which.
namespace lidarsim::testing {

#ifdef LIDARSIM_SANITIZED
inline constexpr bool kSanitized = true;
#else
inline constexpr bool kSanitized = false;
#endif

// `normal` in the plain build, `sanitized` under the sanitizers.
template <typename T>
constexpr T unless_sanitized(T normal, T sanitized) {
  return kSanitized ? sanitized : normal;
}

}  // namespace lidarsim::testing
