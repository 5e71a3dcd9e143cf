#include "qualify/range_noise_cli.h"

#include <cxxopts.hpp>

#include <algorithm>
#include <cmath>
#include <iomanip>
#include <iostream>
#include <nlohmann/json.hpp>
#include <numbers>
#include <sstream>
#include <string>
#include <vector>

#include "common/atomic_file.h"
#include "common/error.h"
#include "data/class_table.h"
#include "data/nuscenes_lidarseg.h"
#include "data/rellis3d.h"
#include "data/semantickitti.h"
#include "pgm/materials.h"
#include "pgm/projection.h"
#include "qualify/range_noise_fit.h"
#include "sensor/range_noise.h"

namespace lidarsim::qualify {

namespace {

using json = nlohmann::json;

// What the maker states for the sensor's range noise (by beam layout name).
struct Datasheet {
  double sigma_m = 0;
  std::string source;
};

constexpr std::size_t kTableMinCount = 200;

Datasheet datasheet_of(const std::string& layout_name) {
  if (layout_name == "hdl64e")
    return {0.02, "Velodyne HDL-64E S2 user's manual, specifications: distance accuracy < 2 cm"};
  if (layout_name == "hdl32e")
    return {0.02, "Velodyne HDL-32E datasheet: accuracy < 2 cm (one sigma at 25 m)"};
  if (layout_name.rfind("os1", 0) == 0 || layout_name.rfind("OS-1", 0) == 0)
    return {0.015, "Ouster OS1 datasheet (gen 1): range repeatability 1 sigma +-1.5 cm at SNR > 250, +-3 cm at "
                   "SNR 100, +-10 cm at SNR 12"};
  return {0, "no datasheet figure recorded for this sensor"};
}

// One labelled scan read from the source.
struct Scan {
  std::vector<pgm::Point> points;
  std::string source;
};

json bins_json(const std::vector<SpreadBin>& bins) {
  json a = json::array();
  for (const auto& b : bins)
    a.push_back({{"lo", b.lo}, {"hi", b.hi}, {"mean", b.mean}, {"n", b.n}, {"sigma_m", b.sigma}, {"median_m", b.median},
                 {"share_beyond_3_sigma", b.tail3}});
  return a;
}

std::string cm(double m) {
  std::ostringstream s;
  s << std::fixed << std::setprecision(2) << 100 * m;
  return s.str();
}

void print_bins(const std::string& title, const std::string& unit, const std::vector<SpreadBin>& bins, double scale,
                int digits, const sensor::RangeNoiseModel* model, const Datasheet& ds) {
  std::cout << "\n" << title << "\n  " << std::left << std::setw(14) << unit << std::right << std::setw(9) << "n"
            << std::setw(11) << "sigma cm" << std::setw(11) << "median cm" << std::setw(9) << ">3sig";
  if (model) std::cout << std::setw(10) << "model cm" << std::setw(10) << "smooth cm";
  std::cout << std::setw(14) << "datasheet cm\n";
  for (const auto& b : bins) {
    std::ostringstream lab;
    lab << std::fixed << std::setprecision(digits) << b.lo * scale << "-" << b.hi * scale;
    std::cout << "  " << std::left << std::setw(14) << lab.str() << std::right << std::setw(9) << b.n << std::setw(11)
              << cm(b.sigma) << std::setw(11) << cm(b.median) << std::setw(9) << std::setprecision(3) << b.tail3;
    if (model) {
      const double mid = b.mean;
      std::cout << std::setw(10) << cm(model->sigma(mid)) << std::setw(10)
                << cm(std::sqrt(model->a * model->a + model->b * model->b * mid * mid));
    }
    std::cout << std::setw(12) << (ds.sigma_m > 0 ? cm(ds.sigma_m) : std::string("-")) << "\n";
  }
}

}  // namespace

int run_range_noise(int argc, char** argv) {
  cxxopts::Options opts("lidar-qualify range-noise",
                        "Range noise of a sensor from its measured labelled scans: residuals of local line fits along "
                        "each beam row on planar classes, measured along the beam (docs/range-noise.md).");
  opts.add_options()
    ("semantickitti", "SemanticKITTI folder (velodyne + labels; HDL-64E)", cxxopts::value<std::string>())
    ("nuscenes-lidarseg", "nuScenes-lidarseg folder (velodyne/*.pcd.bin + labels/*.lidarseg.bin); needs --sensor and "
     "--class-table", cxxopts::value<std::string>())
    ("rellis3d", "RELLIS-3D folder (OS1-64 .bin + .label); needs --sensor and --class-table", cxxopts::value<std::string>())
    ("sensor", "beam layout JSON (default for SemanticKITTI: the built-in HDL-64E)", cxxopts::value<std::string>())
    ("class-table", "foreign ontology -> ours (data/ontologies/*.csv)", cxxopts::value<std::string>())
    ("classes", "classes the model is fitted on, comma-separated (the table by class shows every planar class)",
     cxxopts::value<std::string>()->default_value("road"))
    ("half-window", "neighbours on each side of a return in its beam row", cxxopts::value<int>()->default_value("1"))
    ("bin", "range bin width, m", cxxopts::value<double>()->default_value("5"))
    ("max-range", "last range bin ends here, m", cxxopts::value<double>()->default_value("80"))
    ("max-scans", "at most this many scans (0: all)", cxxopts::value<int>()->default_value("0"))
    ("out", "model JSON to write (sensor/range_noise.h), with the measured tables", cxxopts::value<std::string>())
    ("h,help", "this help");
  const auto a = opts.parse(argc, argv);
  if (a.count("help")) {
    std::cout << opts.help() << "\n";
    return 0;
  }
  if (!a.unmatched().empty()) throw Error("range-noise: unexpected argument \"" + a.unmatched().front() + "\"");
  const int sources = static_cast<int>(a.count("semantickitti") + a.count("nuscenes-lidarseg") + a.count("rellis3d"));
  if (sources != 1) throw Error("range-noise: give exactly one of --semantickitti, --nuscenes-lidarseg, --rellis3d");
  if (!a.count("out")) throw Error("--out: required (the model JSON to write)");
  const double bin = a["bin"].as<double>(), max_range = a["max-range"].as<double>();
  if (!(bin > 0) || !(max_range > bin)) throw Error("range-noise: --bin must be > 0 and --max-range > --bin");
  const int max_scans = a["max-scans"].as<int>();
  RangeFitOptions fo;
  fo.half_window = a["half-window"].as<int>();
  if (fo.half_window < 1 || fo.half_window > 20) throw Error("--half-window: expected 1..20, got " + std::to_string(fo.half_window));

  std::vector<int> fit_classes;
  const std::string class_list = a["classes"].as<std::string>();
  {
    std::stringstream ss(class_list);
    for (std::string name; std::getline(ss, name, ',');) {
      int c = -1;
      try {
        c = pgm::class_from_name(name);
      } catch (const Error& e) {
        throw Error(std::string("--classes: ") + e.what());
      }
      if (std::find(fo.classes.begin(), fo.classes.end(), c) == fo.classes.end())
        throw Error("--classes: \"" + name + "\" is not a planar class (road, parking, sidewalk, other_ground, building, fence)");
      fit_classes.push_back(c);
    }
  }
  pgm::BeamLayout layout = a.count("sensor") ? pgm::BeamLayout::from_file(a["sensor"].as<std::string>())
                                             : pgm::BeamLayout::hdl64e();
  if (!a.count("semantickitti") && !a.count("sensor"))
    throw Error("--sensor: required for this source (data/sensors/hdl32e-nuscenes.json, os1-64-rellis3d.json)");
  std::string dataset, dir;
  std::vector<Scan> scans;
  auto enough = [&] { return max_scans > 0 && static_cast<int>(scans.size()) >= max_scans; };
  if (a.count("semantickitti")) {
    dataset = "semantickitti", dir = a["semantickitti"].as<std::string>();
    for (const auto& f : data::list_semantickitti(dir)) {
      if (!f.label || enough()) continue;  // the fit needs classes
      scans.push_back({data::read_semantickitti_scan(f).points, f.bin.string()});
    }
  } else {
    if (!a.count("class-table")) throw Error("--class-table: required for this source (data/ontologies/*.csv)");
    const auto table = data::read_class_table(a["class-table"].as<std::string>());
    if (a.count("nuscenes-lidarseg")) {
      dataset = "nuscenes-lidarseg", dir = a["nuscenes-lidarseg"].as<std::string>();
      for (const auto& f : data::list_nuscenes_lidarseg(dir))
        if (!enough()) scans.push_back({data::read_nuscenes_lidarseg_scan(f, table).points, f.pcd.string()});
    } else {
      dataset = "rellis3d", dir = a["rellis3d"].as<std::string>();
      for (const auto& f : data::list_rellis3d(dir))
        if (f.label && !enough()) scans.push_back({data::read_rellis3d_scan(f, table).points, f.bin.string()});
    }
  }
  if (scans.empty()) throw input_error(dir, "scans", "no labelled scan found");

  // Residuals of every scan, once per half-window (the main one and its neighbours, to bound the
  // surfaces' own roughness: it grows with the window, the sensor's noise does not).
  std::vector<RangeResidual> all;  // every planar class (the table by class)
  std::vector<int> windows = {1, 2, 3, 5};
  std::vector<std::vector<RangeResidual>> by_window(windows.size());
  for (const auto& s : scans) {
    auto r = scan_range_residuals(s.points, layout, fo, s.source);
    all.insert(all.end(), r.begin(), r.end());
    for (std::size_t w = 0; w < windows.size(); ++w) {
      RangeFitOptions ow = fo;
      ow.half_window = windows[w];
      auto rw = scan_range_residuals(s.points, layout, ow, s.source);
      by_window[w].insert(by_window[w].end(), rw.begin(), rw.end());
    }
  }
  // The model and the tables by range, incidence, intensity and row: the fit classes only (default
  // road: the smoothest surface labelled in every data set, seen at every range), so the surfaces'
  // own structure (facades at range, kerbs) does not pass for sensor noise.
  std::vector<RangeResidual> res;
  for (const auto& r : all)
    if (std::find(fit_classes.begin(), fit_classes.end(), r.class_id) != fit_classes.end()) res.push_back(r);
  if (res.size() < 100) throw input_error(dir, "scans", "only " + std::to_string(res.size()) + " usable neighbourhoods of the fit classes");

  std::vector<double> range_edges;
  for (double e = 0; e <= max_range + 1e-9; e += bin) range_edges.push_back(e);
  const auto by_range = spread_by(res, [](const RangeResidual& r) { return r.range; }, range_edges);
  const SigmaFit fit = fit_sigma_of_range(by_range);
  sensor::RangeNoiseModel model;
  model.sensor = layout.name;
  model.a = fit.a, model.b = fit.b;
  // The table: bins with enough residuals for a spread known to a few per cent (MAD of n: ~1.2/sqrt(n)).
  for (const auto& b : by_range)
    if (b.n >= kTableMinCount) {
      model.table_range_m.push_back(b.mean);
      model.table_sigma_m.push_back(b.sigma);
    }
  std::ostringstream cmd;
  cmd << "lidar-qualify range-noise --" << dataset << " " << dir;
  if (a.count("sensor")) cmd << " --sensor " << a["sensor"].as<std::string>();
  if (a.count("class-table")) cmd << " --class-table " << a["class-table"].as<std::string>();
  cmd << " --classes " << class_list << " --half-window " << fo.half_window << " --bin " << bin << " --max-range " << max_range;
  if (max_scans > 0) cmd << " --max-scans " << max_scans;
  cmd << " --out " << a["out"].as<std::string>();
  model.source = dataset + ": " + std::to_string(scans.size()) + " scans of " + dir + ", " +
                 std::to_string(res.size()) + " neighbourhoods of " + class_list;
  model.validate("range-noise fit");
  const Datasheet ds = datasheet_of(layout.name);

  std::vector<double> inc_edges;
  for (int d = 0; d <= 90; d += 10) inc_edges.push_back(d * std::numbers::pi / 180);
  const auto by_incidence = spread_by(res, [](const RangeResidual& r) { return r.incidence; }, inc_edges);
  auto intensity_key = [](const RangeResidual& r) { return static_cast<double>(r.intensity); };
  const auto by_intensity = spread_by(res, intensity_key, quantile_edges(res, intensity_key, 5));
  std::vector<double> row_edges;
  for (int r = 0; r <= layout.rows(); r += 8) row_edges.push_back(r);
  const auto by_row = spread_by(res, [](const RangeResidual& r) { return r.row; }, row_edges);
  json classes = json::array();
  for (int c : fo.classes) {
    std::vector<RangeResidual> rc;
    for (const auto& r : all)
      if (r.class_id == c) rc.push_back(r);
    if (rc.size() < 50) continue;
    std::vector<float> v;
    for (const auto& r : rc) v.push_back(r.residual);
    classes.push_back({{"class", pgm::class_name(c)}, {"n", rc.size()}, {"sigma_m", robust_sigma(v)},
                       {"by_range", bins_json(spread_by(rc, [](const RangeResidual& r) { return r.range; }, range_edges))}});
  }
  json windows_json = json::array();
  for (std::size_t w = 0; w < windows.size(); ++w) {
    std::vector<float> v;
    for (const auto& r : by_window[w]) v.push_back(r.residual);
    json byc = json::object();
    for (int c : {pgm::cls::road, pgm::cls::sidewalk, pgm::cls::building}) {
      std::vector<float> vc;
      for (const auto& r : by_window[w])
        if (r.class_id == c) vc.push_back(r.residual);
      if (vc.size() >= 50) byc[pgm::class_name(c)] = robust_sigma(vc);
    }
    std::vector<RangeResidual> fit_w;  // the fit classes, by range: does the spread grow with the window at range?
    for (const auto& r : by_window[w])
      if (std::find(fit_classes.begin(), fit_classes.end(), r.class_id) != fit_classes.end()) fit_w.push_back(r);
    windows_json.push_back({{"half_window", windows[w]}, {"n", v.size()}, {"sigma_m", robust_sigma(v)}, {"by_class", byc},
                            {"fit_classes_by_range_m",
                             bins_json(spread_by(fit_w, [](const RangeResidual& r) { return r.range; }, range_edges))}});
  }

  json j;
  j["format"] = "lidarsim-range-noise";
  j["version"] = 1;
  j["sensor"] = model.sensor;
  j["source"] = model.source;
  j["command"] = cmd.str();
  j["form"] = "Gaussian along the beam; sigma(r) from the table (flat below its first range, linear between, "
              "beyond its last range grown as sqrt(a^2 + (b r)^2))";
  j["sigma_m"] = {{"a", model.a}, {"b", model.b}};
  j["table"] = {{"range_m", model.table_range_m}, {"sigma_m", model.table_sigma_m}};
  j["datasheet"] = {{"sigma_m", ds.sigma_m}, {"source", ds.source}};
  j["measured"] = {{"method", "residual along the beam of a line fit to the same row's neighbours (half-window " +
                                  std::to_string(fo.half_window) + "), 1.4826 x MAD per bin; classes " + class_list +
                                  " (by_class: every planar class)"},
                   {"by_range_m", bins_json(by_range)},
                   {"by_incidence_rad", bins_json(by_incidence)},
                   {"by_intensity", bins_json(by_intensity)},
                   {"by_row", bins_json(by_row)},
                   {"by_class", classes},
                   {"by_half_window", windows_json}};
  write_file_atomically(a["out"].as<std::string>(), j.dump(1) + "\n");

  std::cout << "range noise of " << layout.name << " from " << scans.size() << " " << dataset << " scans, "
            << res.size() << " neighbourhoods of " << class_list << " (half-window " << fo.half_window
            << "; " << all.size() << " of every planar class)\n"
            << "datasheet: " << ds.source << "\n"
            << "smooth form: sigma(r) = sqrt(a^2 + (b r)^2), a = " << cm(model.a) << " cm, b = " << std::setprecision(3)
            << 1000 * model.b << " mm per m (" << cm(model.sigma(25)) << " cm at 25 m); the model uses the table of "
            << model.table_range_m.size() << " range bins with >= " << kTableMinCount << " residuals\n";
  print_bins("spread by range (m):", "range m", by_range, 1, 0, &model, ds);
  print_bins("spread by incidence (deg):", "incidence", by_incidence, 180 / std::numbers::pi, 0, nullptr, ds);
  print_bins("spread by intensity (equal-count bins):", "intensity", by_intensity, 1, 2, nullptr, ds);
  print_bins("spread by beam row (lasers, 0 = top):", "rows", by_row, 1, 0, nullptr, ds);
  std::cout << "\nspread by class (cm):";
  for (const auto& c : classes) std::cout << "  " << c["class"].get<std::string>() << " " << cm(c["sigma_m"].get<double>())
                                          << " (n " << c["n"].get<std::size_t>() << ")";
  std::cout << "\nspread by half-window (cm; the surfaces' roughness grows with it, the sensor's noise does not):\n";
  for (const auto& w : windows_json) {
    std::cout << "  K=" << w["half_window"].get<int>() << ": every planar class " << cm(w["sigma_m"].get<double>());
    for (const auto& [k, v] : w["by_class"].items()) std::cout << ", " << k << " " << cm(v.get<double>());
    std::cout << "; " << class_list << " by range:";
    for (const auto& b : w["fit_classes_by_range_m"])
      if (b["n"].get<std::size_t>() >= kTableMinCount)
        std::cout << " " << b["lo"].get<double>() << "-" << b["hi"].get<double>() << " " << cm(b["sigma_m"].get<double>());
    std::cout << "\n";
  }
  std::cout << "wrote " << a["out"].as<std::string>() << "\n";
  return 0;
}

}  // namespace lidarsim::qualify
