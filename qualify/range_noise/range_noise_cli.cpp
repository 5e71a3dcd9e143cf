#include "qualify/range_noise/range_noise_cli.h"

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
#include "qualify/range_noise/range_noise_fit.h"
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

using Scan = LabelledScan;

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

// The command line, checked (in this order, so the first error named stays the same).
struct Args {
  std::string dataset, dir;           // the one source given
  std::string sensor, class_table;    // empty when not given
  std::string class_list, out;
  std::vector<int> fit_classes;
  RangeFitOptions fo;
  double bin = 0, max_range = 0;
  int max_scans = 0;
  pgm::BeamLayout layout;
};

cxxopts::Options range_noise_options() {
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
  return opts;
}

// --classes: each a planar class the fit options know.
std::vector<int> parse_fit_classes(const std::string& class_list, const RangeFitOptions& fo) {
  std::vector<int> fit_classes;
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
  return fit_classes;
}

Args check_args(const cxxopts::ParseResult& a) {
  if (!a.unmatched().empty()) throw Error("range-noise: unexpected argument \"" + a.unmatched().front() + "\"");
  const int sources = static_cast<int>(a.count("semantickitti") + a.count("nuscenes-lidarseg") + a.count("rellis3d"));
  if (sources != 1) throw Error("range-noise: give exactly one of --semantickitti, --nuscenes-lidarseg, --rellis3d");
  if (!a.count("out")) throw Error("--out: required (the model JSON to write)");
  Args g;
  g.out = a["out"].as<std::string>();
  g.bin = a["bin"].as<double>(), g.max_range = a["max-range"].as<double>();
  if (!(g.bin > 0) || !(g.max_range > g.bin)) throw Error("range-noise: --bin must be > 0 and --max-range > --bin");
  g.max_scans = a["max-scans"].as<int>();
  g.fo.half_window = a["half-window"].as<int>();
  if (g.fo.half_window < 1 || g.fo.half_window > 20)
    throw Error("--half-window: expected 1..20, got " + std::to_string(g.fo.half_window));
  g.class_list = a["classes"].as<std::string>();
  g.fit_classes = parse_fit_classes(g.class_list, g.fo);
  if (a.count("sensor")) g.sensor = a["sensor"].as<std::string>();
  if (a.count("class-table")) g.class_table = a["class-table"].as<std::string>();
  g.layout = a.count("sensor") ? pgm::BeamLayout::from_file(g.sensor) : pgm::BeamLayout::hdl64e();
  if (!a.count("semantickitti") && !a.count("sensor"))
    throw Error("--sensor: required for this source (data/sensors/hdl32e-nuscenes.json, os1-64-rellis3d.json)");
  for (const char* source : {"semantickitti", "nuscenes-lidarseg", "rellis3d"})
    if (a.count(source)) g.dataset = source, g.dir = a[source].as<std::string>();
  if (g.dataset != "semantickitti" && g.class_table.empty())
    throw Error("--class-table: required for this source (data/ontologies/*.csv)");
  return g;
}

// The labelled scans of the source (at most --max-scans).
std::vector<Scan> read_scans(const Args& g) { return read_labelled_scans(g.dataset, g.dir, g.class_table, g.max_scans); }

// Half-windows measured beside the main one, to bound the surfaces' own roughness: it grows with
// the window, the sensor's noise does not.
const std::vector<int> kWindows = {1, 2, 3, 5};

struct Residuals {
  std::vector<RangeResidual> all;                        // every planar class (the table by class)
  std::vector<std::vector<RangeResidual>> by_window;     // per kWindows entry
  std::vector<RangeResidual> fit;                        // the fit classes, main half-window
};

bool is_fit_class(const Args& g, int class_id) {
  return std::find(g.fit_classes.begin(), g.fit_classes.end(), class_id) != g.fit_classes.end();
}

Residuals residuals_of(const std::vector<Scan>& scans, const Args& g) {
  Residuals r;
  r.by_window.resize(kWindows.size());
  for (const auto& s : scans) {
    auto rs = scan_range_residuals(s.points, g.layout, g.fo, s.source);
    r.all.insert(r.all.end(), rs.begin(), rs.end());
    for (std::size_t w = 0; w < kWindows.size(); ++w) {
      RangeFitOptions ow = g.fo;
      ow.half_window = kWindows[w];
      auto rw = scan_range_residuals(s.points, g.layout, ow, s.source);
      r.by_window[w].insert(r.by_window[w].end(), rw.begin(), rw.end());
    }
  }
  // The model and the tables by range, incidence, intensity and row: the fit classes only (default
  // road: the smoothest surface labelled in every data set, seen at every range), so the surfaces'
  // own structure (facades at range, kerbs) does not pass for sensor noise.
  for (const auto& x : r.all)
    if (is_fit_class(g, x.class_id)) r.fit.push_back(x);
  if (r.fit.size() < 100)
    throw input_error(g.dir, "scans", "only " + std::to_string(r.fit.size()) + " usable neighbourhoods of the fit classes");
  return r;
}

std::vector<double> range_edges_of(const Args& g) {
  std::vector<double> range_edges;
  for (double e = 0; e <= g.max_range + 1e-9; e += g.bin) range_edges.push_back(e);
  return range_edges;
}

// The model: the smooth form fitted by range, and the table of bins with enough residuals for a
// spread known to a few per cent (MAD of n: ~1.2/sqrt(n)).
sensor::RangeNoiseModel fit_model(const std::vector<SpreadBin>& by_range, const Args& g, std::size_t scans,
                                  std::size_t neighbourhoods) {
  const SigmaFit fit = fit_sigma_of_range(by_range);
  sensor::RangeNoiseModel model;
  model.sensor = g.layout.name;
  model.a = fit.a, model.b = fit.b;
  for (const auto& b : by_range)
    if (b.n >= kTableMinCount) {
      model.table_range_m.push_back(b.mean);
      model.table_sigma_m.push_back(b.sigma);
    }
  model.source = g.dataset + ": " + std::to_string(scans) + " scans of " + g.dir + ", " +
                 std::to_string(neighbourhoods) + " neighbourhoods of " + g.class_list;
  model.validate("range-noise fit");
  return model;
}

// The command that reproduces the fit, with every setting spelled out.
std::string command_of(const Args& g) {
  std::ostringstream cmd;
  cmd << "lidar-qualify range-noise --" << g.dataset << " " << g.dir;
  if (!g.sensor.empty()) cmd << " --sensor " << g.sensor;
  if (!g.class_table.empty()) cmd << " --class-table " << g.class_table;
  cmd << " --classes " << g.class_list << " --half-window " << g.fo.half_window << " --bin " << g.bin << " --max-range "
      << g.max_range;
  if (g.max_scans > 0) cmd << " --max-scans " << g.max_scans;
  cmd << " --out " << g.out;
  return cmd.str();
}

// The measured spread tables beside the model.
struct Tables {
  std::vector<SpreadBin> by_range, by_incidence, by_intensity, by_row;
  json by_class = json::array(), by_half_window = json::array();
};

json by_class_json(const Residuals& r, const Args& g, const std::vector<double>& range_edges) {
  json classes = json::array();
  for (int c : g.fo.classes) {
    std::vector<RangeResidual> rc;
    for (const auto& x : r.all)
      if (x.class_id == c) rc.push_back(x);
    if (rc.size() < 50) continue;
    std::vector<float> v;
    for (const auto& x : rc) v.push_back(x.residual);
    classes.push_back({{"class", pgm::class_name(c)}, {"n", rc.size()}, {"sigma_m", robust_sigma(v)},
                       {"by_range", bins_json(spread_by(rc, [](const RangeResidual& x) { return x.range; }, range_edges))}});
  }
  return classes;
}

json by_half_window_json(const Residuals& r, const Args& g, const std::vector<double>& range_edges) {
  json windows_json = json::array();
  for (std::size_t w = 0; w < kWindows.size(); ++w) {
    std::vector<float> v;
    for (const auto& x : r.by_window[w]) v.push_back(x.residual);
    json byc = json::object();
    for (int c : {pgm::cls::road, pgm::cls::sidewalk, pgm::cls::building}) {
      std::vector<float> vc;
      for (const auto& x : r.by_window[w])
        if (x.class_id == c) vc.push_back(x.residual);
      if (vc.size() >= 50) byc[pgm::class_name(c)] = robust_sigma(vc);
    }
    std::vector<RangeResidual> fit_w;  // the fit classes, by range: does the spread grow with the window at range?
    for (const auto& x : r.by_window[w])
      if (is_fit_class(g, x.class_id)) fit_w.push_back(x);
    windows_json.push_back({{"half_window", kWindows[w]}, {"n", v.size()}, {"sigma_m", robust_sigma(v)}, {"by_class", byc},
                            {"fit_classes_by_range_m",
                             bins_json(spread_by(fit_w, [](const RangeResidual& x) { return x.range; }, range_edges))}});
  }
  return windows_json;
}

Tables tables_of(const Residuals& r, const Args& g, std::vector<SpreadBin> by_range, const std::vector<double>& range_edges) {
  Tables t;
  t.by_range = std::move(by_range);
  std::vector<double> inc_edges;
  for (int d = 0; d <= 90; d += 10) inc_edges.push_back(d * std::numbers::pi / 180);
  t.by_incidence = spread_by(r.fit, [](const RangeResidual& x) { return x.incidence; }, inc_edges);
  auto intensity_key = [](const RangeResidual& x) { return static_cast<double>(x.intensity); };
  t.by_intensity = spread_by(r.fit, intensity_key, quantile_edges(r.fit, intensity_key, 5));
  std::vector<double> row_edges;
  for (int row = 0; row <= g.layout.rows(); row += 8) row_edges.push_back(row);
  t.by_row = spread_by(r.fit, [](const RangeResidual& x) { return x.row; }, row_edges);
  t.by_class = by_class_json(r, g, range_edges);
  t.by_half_window = by_half_window_json(r, g, range_edges);
  return t;
}

void write_model(const Args& g, const sensor::RangeNoiseModel& model, const Tables& t, const Datasheet& ds) {
  json j;
  j["format"] = "lidarsim-range-noise";
  j["version"] = 1;
  j["sensor"] = model.sensor;
  j["source"] = model.source;
  j["command"] = command_of(g);
  j["form"] = "Gaussian along the beam; sigma(r) from the table (flat below its first range, linear between, "
              "beyond its last range grown as sqrt(a^2 + (b r)^2))";
  j["sigma_m"] = {{"a", model.a}, {"b", model.b}};
  j["table"] = {{"range_m", model.table_range_m}, {"sigma_m", model.table_sigma_m}};
  j["datasheet"] = {{"sigma_m", ds.sigma_m}, {"source", ds.source}};
  j["measured"] = {{"method", "residual along the beam of a line fit to the same row's neighbours (half-window " +
                                  std::to_string(g.fo.half_window) + "), 1.4826 x MAD per bin; classes " + g.class_list +
                                  " (by_class: every planar class)"},
                   {"by_range_m", bins_json(t.by_range)},
                   {"by_incidence_rad", bins_json(t.by_incidence)},
                   {"by_intensity", bins_json(t.by_intensity)},
                   {"by_row", bins_json(t.by_row)},
                   {"by_class", t.by_class},
                   {"by_half_window", t.by_half_window}};
  write_file_atomically(g.out, j.dump(1) + "\n");
}

void print_report(const Args& g, const sensor::RangeNoiseModel& model, const Tables& t, const Datasheet& ds,
                  std::size_t scans, const Residuals& r) {
  std::cout << "range noise of " << g.layout.name << " from " << scans << " " << g.dataset << " scans, "
            << r.fit.size() << " neighbourhoods of " << g.class_list << " (half-window " << g.fo.half_window
            << "; " << r.all.size() << " of every planar class)\n"
            << "datasheet: " << ds.source << "\n"
            << "smooth form: sigma(r) = sqrt(a^2 + (b r)^2), a = " << cm(model.a) << " cm, b = " << std::setprecision(3)
            << 1000 * model.b << " mm per m (" << cm(model.sigma(25)) << " cm at 25 m); the model uses the table of "
            << model.table_range_m.size() << " range bins with >= " << kTableMinCount << " residuals\n";
  print_bins("spread by range (m):", "range m", t.by_range, 1, 0, &model, ds);
  print_bins("spread by incidence (deg):", "incidence", t.by_incidence, 180 / std::numbers::pi, 0, nullptr, ds);
  print_bins("spread by intensity (equal-count bins):", "intensity", t.by_intensity, 1, 2, nullptr, ds);
  print_bins("spread by beam row (lasers, 0 = top):", "rows", t.by_row, 1, 0, nullptr, ds);
  std::cout << "\nspread by class (cm):";
  for (const auto& c : t.by_class) std::cout << "  " << c["class"].get<std::string>() << " " << cm(c["sigma_m"].get<double>())
                                             << " (n " << c["n"].get<std::size_t>() << ")";
  std::cout << "\nspread by half-window (cm; the surfaces' roughness grows with it, the sensor's noise does not):\n";
  for (const auto& w : t.by_half_window) {
    std::cout << "  K=" << w["half_window"].get<int>() << ": every planar class " << cm(w["sigma_m"].get<double>());
    for (const auto& [k, v] : w["by_class"].items()) std::cout << ", " << k << " " << cm(v.get<double>());
    std::cout << "; " << g.class_list << " by range:";
    for (const auto& b : w["fit_classes_by_range_m"])
      if (b["n"].get<std::size_t>() >= kTableMinCount)
        std::cout << " " << b["lo"].get<double>() << "-" << b["hi"].get<double>() << " " << cm(b["sigma_m"].get<double>());
    std::cout << "\n";
  }
  std::cout << "wrote " << g.out << "\n";
}

}  // namespace

std::vector<LabelledScan> read_labelled_scans(const std::string& dataset, const std::string& dir,
                                              const std::string& class_table, int max_scans) {
  std::vector<LabelledScan> scans;
  auto enough = [&] { return max_scans > 0 && static_cast<int>(scans.size()) >= max_scans; };
  if (dataset == "semantickitti") {
    for (const auto& f : data::list_semantickitti(dir)) {
      if (!f.label || enough()) continue;  // the fit needs classes
      scans.push_back({data::read_semantickitti_scan(f).points, f.bin.string()});
    }
  } else {
    const auto table = data::read_class_table(class_table);
    if (dataset == "nuscenes-lidarseg") {
      for (const auto& f : data::list_nuscenes_lidarseg(dir))
        if (!enough()) scans.push_back({data::read_nuscenes_lidarseg_scan(f, table).points, f.pcd.string()});
    } else {
      for (const auto& f : data::list_rellis3d(dir))
        if (f.label && !enough()) scans.push_back({data::read_rellis3d_scan(f, table).points, f.bin.string()});
    }
  }
  if (scans.empty()) throw input_error(dir, "scans", "no labelled scan found");
  return scans;
}

int run_range_noise(int argc, char** argv) {
  cxxopts::Options opts = range_noise_options();
  const auto a = opts.parse(argc, argv);
  if (a.count("help")) {
    std::cout << opts.help() << "\n";
    return 0;
  }
  const Args g = check_args(a);
  const std::vector<Scan> scans = read_scans(g);
  const Residuals r = residuals_of(scans, g);
  const std::vector<double> range_edges = range_edges_of(g);
  auto by_range = spread_by(r.fit, [](const RangeResidual& x) { return x.range; }, range_edges);
  const sensor::RangeNoiseModel model = fit_model(by_range, g, scans.size(), r.fit.size());
  const Datasheet ds = datasheet_of(g.layout.name);
  const Tables t = tables_of(r, g, std::move(by_range), range_edges);
  write_model(g, model, t, ds);
  print_report(g, model, t, ds, scans.size(), r);
  return 0;
}

}  // namespace lidarsim::qualify
