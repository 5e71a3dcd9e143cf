// The KPI manager's inlined draws (sensor/kpi_noise.h) against the libstdc++ distributions they
// replace: the shipped model and the closed-loop tests were made with those, so every draw must
// be the same double, bit for bit, and take the same number of engine outputs.
#include <gtest/gtest.h>

#include <cstring>
#include <random>

#include "sensor/kpi_noise.h"

namespace lidarsim::sensor {
namespace {

bool same_bits(double a, double b) { return std::memcmp(&a, &b, sizeof a) == 0; }

#ifdef __GLIBCXX__
TEST(KpiDraws, UniformIsLibstdcxxUniformRealBitForBit) {
  KpiRng a(21), b(21);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  for (int i = 0; i < 200000; ++i) {
    const double x = kpi_uniform(a), y = u(b);
    ASSERT_TRUE(same_bits(x, y)) << "draw " << i << ": " << x << " vs " << y;
  }
  EXPECT_EQ(a(), b()) << "the same number of engine outputs";
}

TEST(KpiDraws, UniformNeverReachesOne) {
  // An engine output that rounds to 2^64 as a double: the largest double below 1, as libstdc++.
  struct Top {
    using result_type = std::uint64_t;
    static constexpr result_type min() { return 0; }
    static constexpr result_type max() { return ~result_type{0}; }
    result_type operator()() { return ~result_type{0}; }
  } top;
  const double x = std::uniform_real_distribution<double>(0.0, 1.0)(top);
  EXPECT_LT(x, 1.0);
  const double y = static_cast<double>(top()) * 0x1p-64;
  EXPECT_EQ(y, 1.0) << "the case the clamp is for";
}

TEST(KpiDraws, NormalIsAFreshLibstdcxxNormalBitForBit) {
  KpiRng a(22), b(22);
  for (int i = 0; i < 200000; ++i) {
    const double x = kpi_normal(a), y = std::normal_distribution<double>(0.0, 1.0)(b);
    ASSERT_TRUE(same_bits(x, y)) << "draw " << i << ": " << x << " vs " << y;
  }
  EXPECT_EQ(a(), b());
}
#endif

// InnovationSampler against sample_innovation (which keeps the std:: distributions): the same
// draws for every innovation type, including the mixture's precomputed sigmas.
TEST(KpiDraws, InnovationSamplerGivesSampleInnovationsDrawsBitForBit) {
  const Innovation cases[] = {{Innovation::Type::Gaussian, 0, 0, 1},
                              {Innovation::Type::Mixture, 0, 0.05, 4},
                              {Innovation::Type::Mixture, 0, 0.0191348, 11.4543},
                              {Innovation::Type::StudentT, 5, 0, 1},
                              {Innovation::Type::StudentT, 3.5, 0, 1}};
  int k = 0;
  for (const Innovation& in : cases) {
    SCOPED_TRACE(k);
    const InnovationSampler sampler(in);
    KpiRng a(30 + k), b(30 + k);
    for (int i = 0; i < 50000; ++i) {
      const double x = sampler(a), y = sample_innovation(in, b);
      ASSERT_TRUE(same_bits(x, y)) << "draw " << i << ": " << x << " vs " << y;
    }
    EXPECT_EQ(a(), b());
    ++k;
  }
}

TEST(KpiDraws, Ar1StepOfOneFrameWithItsRootGivenIsAr1Step) {
  KpiRng rng(40);
  for (const double rho : {0.0, 0.3, 0.9, 0.99, -0.5}) {
    const double root = std::sqrt(std::max(0.0, 1 - rho * rho));
    double z1 = 0.3, z2 = 0.3;
    for (int i = 0; i < 1000; ++i) {
      const double eps = kpi_normal(rng);
      z1 = ar1_step(z1, rho, 1, eps);
      z2 = ar1_step_1(z2, rho, root, eps);
      ASSERT_TRUE(same_bits(z1, z2)) << rho << " step " << i;
    }
  }
}

}  // namespace
}  // namespace lidarsim::sensor
