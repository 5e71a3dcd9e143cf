#include "qualify/returns/returns_places.h"

#include <algorithm>

#include "common/error.h"
#include "data/class_table.h"
#include "data/import.h"
#include "data/nuscenes_lidarseg.h"

namespace lidarsim::qualify {

namespace fs = std::filesystem;

namespace {

// A bundled file by its path in the source tree, found from the working directory or the build's.
std::string bundled(const std::string& relative) {
  if (fs::exists(relative)) return relative;
  const fs::path in_source = fs::path(LIDARSIM_SOURCE_DIR) / relative;
  return fs::exists(in_source) ? in_source.string() : relative;
}

data::Dataset import_place_dir(const ReturnPlace& p, const fs::path& dir) {
  data::ImportOptions o;
  o.extra_channels = {"height"};
  o.include_unlabelled = true;  // scans without semantic labels still say which beams returned
  if (p.format == "semantickitti") return data::import_semantickitti(dir, o);
  if (p.format == "kitti_object") return data::import_kitti_object(dir, o);
  if (p.format == "rellis3d") {
    o.layout = pgm::BeamLayout::from_file(bundled("data/sensors/os1-64-rellis3d.json"));
    o.class_table = bundled("data/ontologies/rellis3d.csv");
    return data::import_dataset(data::SourceFormat::Rellis3d, dir, o);
  }
  if (p.format == "nuscenes_lidarseg")
    return data::import_nuscenes_lidarseg(dir, pgm::BeamLayout::from_file(bundled("data/sensors/hdl32e-nuscenes.json")),
                                          data::read_class_table(bundled("data/ontologies/nuscenes-lidarseg.csv")), o);
  throw Error("--place " + p.name + ": unknown format \"" + p.format +
              "\" (expected semantickitti, kitti_object, rellis3d or nuscenes_lidarseg)");
}

}  // namespace

std::vector<ReturnPlace> parse_return_places(const std::vector<std::string>& specs) {
  std::vector<ReturnPlace> places;
  for (const auto& spec : specs) {
    const auto eq = spec.find('='), colon = spec.find(':', eq == std::string::npos ? 0 : eq);
    if (eq == std::string::npos || colon == std::string::npos || eq == 0)
      throw Error("--place: expected NAME=FORMAT:DIR, got \"" + spec + "\"");
    const std::string name = spec.substr(0, eq), format = spec.substr(eq + 1, colon - eq - 1);
    if (colon + 1 == spec.size()) throw Error("--place " + name + ": no folder given");
    auto same = std::find_if(places.begin(), places.end(), [&](const ReturnPlace& q) { return q.name == name; });
    if (same == places.end()) {
      places.push_back({name, format, {spec.substr(colon + 1)}, {}, {}, {}});
    } else if (same->format != format) {
      throw Error("--place " + name + ": given as " + same->format + " and as " + format);
    } else {
      same->dirs.emplace_back(spec.substr(colon + 1));
    }
  }
  return places;
}

void load_return_place(ReturnPlace& p, const pgm::ReturnTargetOptions& rule) {
  for (const auto& dir : p.dirs) {
    const data::Dataset d = import_place_dir(p, dir);
    if (p.targets.empty()) p.layout = d.layout;
    else if (!(d.layout == p.layout))
      throw Error("--place " + p.name + ": " + dir.string() + " has another beam layout (" + d.layout.difference(p.layout) + ")");
    for (int f = 0; f < d.size(); ++f) {
      p.targets.push_back(pgm::return_target(d.frame_pgm(f), rule));
      p.heights.push_back(p.targets.back().sensor_height_m);
    }
  }
}

}  // namespace lidarsim::qualify
