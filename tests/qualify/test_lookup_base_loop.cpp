// The lookup base of lidar-train --lookup-base=classes is the intensity loop's lookup-beam base
// (class x 5 m range + per-beam offset table): the untrained model predicts exactly what the loop
// scores, cell by cell, and the trainer reports the same held-out MAE for the table alone.
#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <filesystem>

#include "data/frame_source.h"
#include "data/reference_sensor.h"
#include "nn/receptive_field.h"
#include "qualify/intensity/intensity.h"
#include "train/lookup_fit.h"
#include "train/trainer.h"

namespace fs = std::filesystem;
using namespace lidarsim;

TEST(LookupBaseLoop, UntrainedModelEqualsTheLoopsClassRangePerBeamTable) {
  const fs::path dir = fs::temp_directory_path() / ("lidarsim_lookup_base_loop_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  data::ReferenceScanOptions o;
  o.effect = data::IntensityEffect::BeamGain;  // a per-laser effect: the per-beam table matters
  o.seed = 31;
  data::write_reference_semantickitti(dir, o);
  const data::Dataset ds = qualify::import_for_qualify(dir);
  fs::remove_all(dir);

  // The loop with the lookup-beam base (the bundled depth 3, the guarded split as it is): its base
  // is that table, so its held-out MAE before any effect is the table's.
  qualify::IntensityLoopOptions lo;
  lo.base_model = qualify::IntensityBase::LookupBeam;
  lo.folds = 1;
  const nlohmann::json j = qualify::loop_intensity(ds, lo);
  const double loop_mae = j["before"].get<double>();
  const data::SectorSplit split = qualify::intensity_split(ds, "guarded", 3);
  const qualify::IntensityCells c = qualify::intensity_cells(ds, split);
  const std::vector<double> table = qualify::lookup_beam_prediction(c, ds.rows());
  double abs_sum = 0;
  long held = 0;
  for (std::size_t i = 0; i < c.size(); ++i)
    if (c.held_out[i]) abs_sum += std::abs(table[i] - c.measured[i]), ++held;
  EXPECT_NEAR(abs_sum / held, loop_mae, 1e-12);

  // The untrained lidar-train model with that lookup base (base 8, depth 3: the same split).
  pgm::EncoderConfig encoder;
  encoder.channels = {"range", "class", "material"};
  encoder.class_groups = train::one_group_per_class();
  nn::UNetConfig arch{encoder.input_channels(), 1, 8, 3};
  arch.lookup = train::lookup_base_config(encoder, ds.rows());
  ASSERT_EQ(data::guarded_split(nn::receptive_field_half_width(arch), ds.cols()).describe(ds.cols()),
            split.describe(ds.cols()));
  const auto source = data::memory_frame_source(ds, "reference");
  const train::TrainingFrames frames({source.get()}, encoder, split);
  nn::UNet model(arch);
  model.init(1);
  train::set_lookup_base(model, train::fit_lookup_base(arch.lookup, frames, ds.cols(), train::BeamFit::loop));
  const nn::Tensor pred = train::predict_dataset(model, encoder, ds);
  const long plane = static_cast<long>(ds.rows()) * ds.cols();
  double worst = 0;
  for (std::size_t i = 0; i < c.size(); ++i)
    worst = std::max(worst, std::abs(pred.image(c.frame[i])[c.cell[i] % plane] - table[i]));
  EXPECT_LT(worst, 1e-5);  // float table vs the loop's doubles: every cell, fit and held out

  // Through the trainer: the table alone scores what the loop scores.
  train::TrainConfig t;
  t.encoder.channels = encoder.channels;
  t.base = 8, t.depth = 3;
  t.lookup_base = true, t.lookup_form = "classes";
  t.epochs = 1, t.steps_per_epoch = 1, t.batch = 1, t.crop_columns = 64;
  t.threads = 1, t.out.clear(), t.progress = false;
  const train::TrainResult r = train::train_on(t, {&ds}, {"reference"});
  ASSERT_TRUE(r.lookup_validation.has_value());
  EXPECT_NEAR(r.lookup_validation->mae, loop_mae, 1e-6);
  EXPECT_EQ(r.lookup_validation->cells, held);
}
