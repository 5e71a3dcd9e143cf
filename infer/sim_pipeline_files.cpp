// The SimPipeline functions that read or write HDF5 checkpoints, in a translation unit of their
// own: code that builds a pipeline from a weights file (the OSMP FMU) then links no HDF5.
#include "common/error.h"
#include "infer/sim_pipeline.h"
#include "nn/checkpoint.h"
#include "nn/unet.h"
#include "pgm/encoder.h"

namespace lidarsim::infer {

SimPipeline SimPipeline::from_files(const std::filesystem::path& scenario, const std::filesystem::path& kpi_model,
                                    const std::filesystem::path& intensity_checkpoint, SimOptions options) {
  sensor::Scenario s = sensor::read_scenario(scenario);
  if (options.sensor) use_sensor(s, *options.sensor);
  sensor::KpiModel k = sensor::load_kpi_model(kpi_model);
  std::unique_ptr<IntensityModel> m;
  if (options.intensity && options.point_cloud) {
    m = std::make_unique<IntensityModel>(IntensityModel::load(intensity_checkpoint));
    m->set_kernel_mode(options.kernels);
  }
  return SimPipeline(std::move(s), std::move(k), std::move(m), options);
}

void write_untrained_checkpoint(const std::filesystem::path& path, int base, int depth, std::uint64_t seed,
                                const pgm::BeamLayout& layout) {
  const pgm::EncoderConfig encoder;
  nn::UNetConfig config;
  config.in_channels = encoder.input_channels();
  config.base = base;
  config.depth = depth;
  nn::UNet model(config);
  model.init(seed);
  nn::Checkpoint meta;
  meta.unet = config;
  meta.attributes["encoder"] = encoder.to_json();
  meta.attributes["beam_layout"] = layout.to_json();
  meta.attributes["note"] = "untrained (He-initialised) weights for tests and benchmarks; not a model";
  nn::save_checkpoint(path, model, nullptr, meta);
}

}  // namespace lidarsim::infer
