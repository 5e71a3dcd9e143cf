// Terms on the sampled spread (infer/intensity_spread_terms.h): the file's errors name the field,
// the factor at a cell reads the row, column and channels, and the model's scale (and so its
// draws) is multiplied by it.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <string>
#include <vector>

#include "common/error.h"
#include "infer/intensity_model.h"
#include "infer/intensity_spread_terms.h"
#include "pgm/materials.h"
#include "tests/support/constant_spread_checkpoint.h"

using namespace lidarsim;

namespace {

pgm::PolarGridMap spread_terms_map() {
  pgm::PolarGridMap map(pgm::BeamLayout::uniform(16, 2.0, -24.0, 64), {"range", "class", "material", "intensity", "mask"});
  for (int r = 0; r < map.rows(); ++r)
    for (int c = 0; c < map.cols(); ++c) {
      map.at(map.channel_index("range"), r, c) = 5.f + r;
      map.at(map.channel_index("class"), r, c) = static_cast<float>(c < 32 ? pgm::cls::car : pgm::cls::road);
      map.at(map.channel_index("material"), r, c) = 1.f;
      map.at(map.channel_index("mask"), r, c) = 1.f;
    }
  return map;
}

std::string terms_text(const std::string& terms) {
  return R"({"format": "lidarsim-intensity-spread-terms", "version": 1, "source": "test", "terms": )" + terms + "}";
}

}  // namespace

TEST(IntensitySpreadTerms, RoundTripAndErrorsNameTheField) {
  const auto t = infer::parse_intensity_spread_terms(terms_text(R"([{"feature": "laser", "width": 1, "factor": [1, 2]}])"), "t.json");
  ASSERT_EQ(t.terms.size(), 1u);
  EXPECT_EQ(infer::parse_intensity_spread_terms(infer::intensity_spread_terms_json(t), "u.json").terms[0].factor,
            t.terms[0].factor);
  auto error_of = [](const std::string& text) {
    try {
      infer::parse_intensity_spread_terms(text, "t.json");
    } catch (const Error& e) {
      return std::string(e.what());
    }
    return std::string();
  };
  EXPECT_NE(error_of(terms_text(R"([{"feature": "laser", "width": 1, "factor": [1, -2]}])")).find("terms[0].factor"), std::string::npos);
  EXPECT_NE(error_of(terms_text(R"([{"feature": "colour", "width": 1, "factor": [1]}])")).find("terms[0].feature"), std::string::npos);
  EXPECT_NE(error_of(terms_text(R"([{"feature": "laser", "width": 0, "factor": [1]}])")).find("terms[0].width"), std::string::npos);
  EXPECT_NE(error_of(R"({"format": "lidarsim-intensity-spread-terms", "version": 2, "terms": []})").find("version"), std::string::npos);
  EXPECT_NE(error_of(R"({"format": "something else", "version": 1, "terms": []})").find("t.json"), std::string::npos);
}

TEST(IntensitySpreadTerms, FactorsMultiplyTheHeadsScaleAndTheDrawsFollow) {
  const pgm::PolarGridMap map = spread_terms_map();
  // Mean 0.4, Laplace scale 0.02 at every cell.
  infer::IntensityModel model =
      infer::IntensityModel::load(lidarsim::testing::constant_spread_checkpoint("spread_terms", 0.4f, 0.02f));
  std::vector<float> mean, plain, scaled;
  model.predict_distribution(map, mean, plain);
  // Rows 0-7 at 3 x, and cars (columns 0-31) at 2 x: the two multiply.
  std::vector<double> laser(16, 1.0);
  std::fill(laser.begin(), laser.begin() + 8, 3.0);
  std::vector<double> by_class(pgm::cls::count, 1.0);
  by_class[pgm::cls::car] = 2.0;
  model.set_spread_terms({{"laser", 1, laser, ""}, {"class", 1, by_class, ""}});
  model.predict_distribution(map, mean, scaled);
  const int W = map.cols();
  EXPECT_NEAR(scaled[0 * W + 0] / plain[0], 6.0, 1e-5);     // row 0, a car
  EXPECT_NEAR(scaled[0 * W + 40] / plain[40], 3.0, 1e-5);   // row 0, road
  EXPECT_NEAR(scaled[10 * W + 0] / plain[10 * W], 2.0, 1e-5);  // row 10, a car
  EXPECT_NEAR(scaled[10 * W + 40] / plain[10 * W + 40], 1.0, 1e-6);
  // The draws spread by the same factors: mean absolute deviation of row 0's road cells against row 10's.
  model.sample_from_spread({3}, "test");
  double wide = 0, narrow = 0;
  for (int f = 0; f < 40; ++f) {
    std::vector<float> drawn;
    model.predict(map, drawn, static_cast<std::uint64_t>(f));
    for (int c = 32; c < W; ++c) wide += std::abs(drawn[0 * W + c] - 0.4), narrow += std::abs(drawn[10 * W + c] - 0.4);
  }
  EXPECT_NEAR(wide / narrow, 3.0, 0.3);
}

TEST(IntensitySpreadTerms, ATermOnAChannelTheMapLacksIsRefusedNamingIt) {
  pgm::PolarGridMap map(pgm::BeamLayout::uniform(4, 2.0, -4.0, 8), {"range", "mask"});
  std::vector<sensor::RangeNoiseTerm> terms = {{"incidence", 10, {1.0, 2.0}, ""}};
  try {
    infer::SpreadTermFactor f(terms, map);
    FAIL() << "expected an error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("\"incidence\""), std::string::npos) << e.what();
  }
}
