#include <gtest/gtest.h>

#include "common/error.h"
#include "pgm/encoder.h"

using namespace lidarsim::pgm;

namespace {
PolarGridMap small_map() {
  PolarGridMap m(BeamLayout::uniform(2, 1, -1, 4), {"range", "class", "material", "intensity", "mask", "height"});
  // One return at (0, 1): a car at 40 m, car paint, intensity 0.3, 0.5 m high.
  m.at(m.channel_index("range"), 0, 1) = 40;
  m.at(m.channel_index("class"), 0, 1) = cls::car;
  m.at(m.channel_index("material"), 0, 1) = material::car_paint;
  m.at(m.channel_index("intensity"), 0, 1) = 0.3f;
  m.at(m.channel_index("mask"), 0, 1) = 1;
  m.at(m.channel_index("height"), 0, 1) = 0.5f;
  // An empty cell with garbage in it must still encode as zeros.
  m.at(m.channel_index("range"), 1, 3) = 99;
  return m;
}
}  // namespace

TEST(Encoder, RangeIsNormalisedAndClassAndMaterialAreOneHot) {
  EncoderConfig cfg;
  const auto in = encode_input(small_map(), cfg);
  const auto names = cfg.input_names();
  ASSERT_EQ(in.shape().c, static_cast<int>(names.size()));
  EXPECT_EQ(in.shape().c, 1 + static_cast<int>(default_class_groups().size()) + material_count());
  auto idx = [&](const std::string& n) { return int(std::find(names.begin(), names.end(), n) - names.begin()); };
  EXPECT_FLOAT_EQ(in.at(0, idx("range"), 0, 1), 0.5f);
  EXPECT_EQ(in.at(0, idx("class:vehicle"), 0, 1), 1.f);
  EXPECT_EQ(in.at(0, idx("class:road"), 0, 1), 0.f);
  EXPECT_EQ(in.at(0, idx("material:car_paint"), 0, 1), 1.f);
  EXPECT_EQ(in.at(0, idx("material:unknown"), 0, 1), 0.f);
  // Empty cells are zero in every input channel.
  for (int c = 0; c < in.shape().c; ++c) EXPECT_EQ(in.at(0, c, 1, 3), 0.f) << names[c];
}

TEST(Encoder, TargetAndMaskComeFromIntensityAndReturns) {
  const auto m = small_map();
  const auto t = encode_target(m, EncoderConfig{});
  const auto k = encode_mask(m);
  EXPECT_FLOAT_EQ(t.at(0, 0, 0, 1), 0.3f);
  EXPECT_EQ(k.at(0, 0, 0, 1), 1.f);
  EXPECT_EQ(k.at(0, 0, 1, 3), 0.f);
  EXPECT_EQ(t.at(0, 0, 1, 3), 0.f);
}

TEST(Encoder, ExtraChannelUsesScaleAndConfigRoundTripsThroughJson) {
  EncoderConfig cfg;
  cfg.channels = {"range", "height", "class"};
  cfg.class_one_hot = false;
  cfg.range_max_m = 50;
  cfg.scales["height"] = {0.25f, 2.f};
  const auto back = EncoderConfig::from_json(cfg.to_json(), "ckpt");
  EXPECT_EQ(back.channels, cfg.channels);
  EXPECT_EQ(back.range_max_m, 50.f);
  EXPECT_FALSE(back.class_one_hot);
  EXPECT_EQ(back.input_names(), cfg.input_names());
  EXPECT_EQ(back.class_groups.size(), cfg.class_groups.size());
  const auto in = encode_input(small_map(), back);
  ASSERT_EQ(in.shape().c, 3);
  EXPECT_FLOAT_EQ(in.at(0, 0, 0, 1), 0.8f);                    // 40 / 50
  EXPECT_FLOAT_EQ(in.at(0, 1, 0, 1), (0.5f - 0.25f) * 2.f);    // (height - offset) * scale
  EXPECT_FLOAT_EQ(in.at(0, 2, 0, 1), float(cls::car) / class_count());
}

TEST(Encoder, MalformedConfigAndMissingChannelNameTheProblem) {
  try {
    EncoderConfig::from_json(R"({"version":1})", "model.h5: /config encoder");
    FAIL();
  } catch (const lidarsim::Error& e) {
    EXPECT_NE(std::string(e.what()).find("model.h5"), std::string::npos) << e.what();
  }
  EncoderConfig cfg;
  cfg.channels = {"range", "incidence"};
  try {
    cfg.check_channels({"range", "class", "material"}, "data.h5");
    FAIL();
  } catch (const lidarsim::Error& e) {
    EXPECT_NE(std::string(e.what()).find("incidence"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("data.h5"), std::string::npos) << e.what();
  }
}
