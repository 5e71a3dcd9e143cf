// The simulation pipeline with the shipped return model (lidar-infer sim --returns): fewer
// returns than ideal at the model's rate, and the draws of frame k depend on k, not on which
// frames ran before it.
#include <gtest/gtest.h>

#include <memory>

#include "sensor/return_model.h"
#include "tests/e2e/sim_pipeline_fixture.h"

namespace lidarsim::sim_test {

TEST_F(SimPipelineTest, ReturnModelDropsBeamsAtItsRateAndFrameKDrawsTheSameWhateverRanBefore) {
  auto with_returns = [](std::uint64_t seed) {
    infer::SimOptions o;
    o.seed = seed;
    o.intensity = false;
    o.returns = std::make_shared<sensor::ReturnModel>(
        sensor::ReturnModel::load((testing::source_dir() / "data/models/returns_hdl64e.json").string()));
    return infer::SimPipeline::from_files(scenario(), kpi(), "", o);
  };
  infer::SimOptions ideal_options;
  ideal_options.intensity = false;
  auto ideal = infer::SimPipeline::from_files(scenario(), kpi(), "", ideal_options);
  auto a = with_returns(5), b = with_returns(5);
  infer::SimFrame fi, fa, fb;
  ideal.run_frame(2, fi);
  for (int k = 0; k <= 2; ++k) a.run_frame(k, fa);
  b.run_frame(2, fb);
  EXPECT_EQ(fa.pgm.data(), fb.pgm.data()) << "frame 2 must not depend on frames 0 and 1 having run";
  EXPECT_EQ(fa.cloud.size(), static_cast<std::size_t>(fa.returns));
  const double kept = static_cast<double>(fa.returns) / fi.returns;
  EXPECT_GT(kept, 0.75);
  EXPECT_LT(kept, 0.97);
  auto c = with_returns(6);
  infer::SimFrame fc;
  c.run_frame(2, fc);
  EXPECT_NE(fc.pgm.data(), fa.pgm.data()) << "another seed draws other beams";
}

}  // namespace lidarsim::sim_test
