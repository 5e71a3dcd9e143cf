#include "data/import.h"

#include <omp.h>

#include <algorithm>
#include <exception>
#include <memory>

#include "common/error.h"
#include "data/dataset_writer.h"
#include "data/class_table.h"
#include "data/kitti_object.h"
#include "data/nuscenes.h"
#include "data/ouster.h"
#include "data/rellis3d.h"
#include "data/semantickitti.h"

namespace lidarsim::data {
namespace fs = std::filesystem;
namespace {

// One scan as its reader returns it.
struct RecordedScan {
  std::vector<pgm::Point> points;
  std::vector<fs::path> sources;
  std::string note;  // for the user (unknown labels, ...), empty when nothing to say
};

// One scan to import: its ids and how to read it (called on any thread).
struct ScanJob {
  std::string id;  // frame id in /frames
  FramePlace place;
  std::string path;  // named in projection errors
  std::function<RecordedScan()> read;
};

struct ProjectedScan {
  pgm::PolarGridMap pgm;
  std::string row_mode;
  std::vector<fs::path> sources;
  std::string note;
  bool skipped = false;  // unreadable, and the user asked to skip such scans
};

// How many scans the listing found, and how many it left out for want of labels.
struct ListCounts {
  std::size_t found = 0;
  int unlabelled = 0;
};

void note_counts(const ImportOptions& o, const ListCounts& c, int read, int unreadable) {
  if (!o.note) return;
  std::string why;
  if (c.unlabelled) why += std::to_string(c.unlabelled) + " without labels";
  if (unreadable) why += std::string(why.empty() ? "" : ", ") + std::to_string(unreadable) + " unreadable";
  const std::size_t skipped = static_cast<std::size_t>(c.unlabelled + unreadable);
  o.note("found " + std::to_string(c.found) + " scans, read " + std::to_string(read) + ", skipped " +
         std::to_string(skipped) + (why.empty() ? "" : " (" + why + ")") +
         (c.found > static_cast<std::size_t>(read) + skipped ? "; the rest outside --first/--max-frames" : ""));
}

template <typename T>
std::vector<T> window(const std::vector<T>& all, const ImportOptions& o) {
  const std::size_t first = std::min<std::size_t>(std::max(o.first, 0), all.size());
  std::size_t last = all.size();
  if (o.max_frames > 0) last = std::min(last, first + static_cast<std::size_t>(o.max_frames));
  return std::vector<T>(all.begin() + first, all.begin() + last);
}

void check_columns(int columns) {
  if (columns < 16 || columns % 16 != 0)
    throw Error("import: columns: must be a positive multiple of 16 (the validation split cuts 16 sectors), got " +
                std::to_string(columns));
}

std::vector<ScanJob> semantickitti_jobs(const fs::path& dir, const ImportOptions& options, ListCounts& counts) {
  std::vector<ScanFiles> scans;
  int unlabelled = 0;
  const auto listed = list_semantickitti(dir, options.sequences);
  for (const auto& s : listed) {
    if (s.label || options.include_unlabelled) scans.push_back(s);
    else ++unlabelled;
  }
  counts = {listed.size(), unlabelled};
  if (unlabelled && options.note)
    options.note("skipped " + std::to_string(unlabelled) + " scans without labels (--include-unlabelled reads them)");
  scans = window(scans, options);
  if (scans.empty())
    throw input_error(dir.string(), "scans", options.include_unlabelled ? "no velodyne/*.bin scans found"
                                                                         : "no labelled scans (velodyne/*.bin with labels/*.label) found");
  std::vector<ScanJob> jobs;
  for (const auto& s : scans) {
    jobs.push_back({"semantickitti/" + s.sequence + "/" + s.id, {"semantickitti", s.sequence, s.id}, s.bin.string(), [s] {
                      LabelledScan scan = read_semantickitti_scan(s);
                      RecordedScan r{std::move(scan.points), std::move(scan.sources), ""};
                      if (scan.unknown_labels)
                        r.note = s.label->string() + ": " + std::to_string(scan.unknown_labels) +
                                 " labels outside the SemanticKITTI classes, imported as unlabeled";
                      return r;
                    }});
  }
  return jobs;
}

std::vector<ScanJob> kitti_object_jobs(const fs::path& dir, const ImportOptions& options, ListCounts& counts) {
  const auto listed = list_kitti_object(dir);
  counts.found = listed.size();
  const auto frames = window(listed, options);
  if (frames.empty()) throw input_error(dir.string(), "frames", "no velodyne/*.bin frames found");
  std::vector<ScanJob> jobs;
  // KITTI object frames do not say which drive they come from: each frame is its own place.
  for (const auto& f : frames)
    jobs.push_back({"kitti_object/" + f.id, {"kitti_object", "", f.id}, f.bin.string(), [f] {
                      KittiObjectScan scan = read_kitti_object_scan(f);
                      return RecordedScan{std::move(scan.points), std::move(scan.sources), ""};
                    }});
  return jobs;
}

std::vector<ScanJob> nuscenes_jobs(const fs::path& dir, const ImportOptions& options, ListCounts& counts) {
  const auto listed = list_nuscenes(dir);
  counts.found = listed.size();
  const auto files = window(listed, options);
  if (files.empty()) throw input_error(dir.string(), "sweeps", "no *.pcd.bin files found");
  std::vector<ScanJob> jobs;
  for (const auto& f : files) {
    const std::string log = f.log.empty() ? "-" : f.log;
    jobs.push_back({"nuscenes/" + log + "/" + f.timestamp, {"nuscenes", f.log, f.timestamp}, f.path.string(), [f] {
                      return RecordedScan{read_nuscenes_pcd_bin(f.path), {f.path}, ""};
                    }});
  }
  return jobs;
}

std::vector<ScanJob> rellis3d_jobs(const fs::path& dir, const ImportOptions& options, ListCounts& counts) {
  if (options.class_table.empty()) throw Error("import: rellis3d needs a class table (data/ontologies/rellis3d.csv)");
  auto table = std::make_shared<const ClassTable>(read_class_table(options.class_table));
  const auto listed = list_rellis3d(dir);
  counts.found = listed.size();
  const auto files = window(listed, options);
  std::vector<ScanJob> jobs;
  for (const auto& f : files) {
    jobs.push_back({"rellis3d/" + f.sequence + "/" + f.id, {"rellis3d", f.sequence, f.id}, f.bin.string(), [f, table] {
                      Rellis3dScan scan = read_rellis3d_scan(f, *table);
                      RecordedScan r{std::move(scan.points), std::move(scan.sources), ""};
                      std::string unmapped;
                      for (const auto& [name, n] : scan.unmapped)
                        unmapped += (unmapped.empty() ? "" : ", ") + name + " " + std::to_string(n);
                      if (!unmapped.empty())
                        r.note = f.bin.string() + ": points of RELLIS classes without a class of ours, imported as "
                                 "unlabeled: " + unmapped;
                      if (!f.ply)
                        r.note += std::string(r.note.empty() ? "" : "; ") + f.bin.string() +
                                  ": no PLY beside it, intensity is the .bin's rescaled value";
                      return r;
                    }});
  }
  return jobs;
}

std::vector<fs::path> ouster_pcaps(const fs::path& dir) {
  std::error_code ec;
  if (fs::is_regular_file(dir, ec)) return {dir};
  if (!fs::is_directory(dir, ec)) throw input_error(dir.string(), "pcap", "not found");
  std::vector<fs::path> pcaps;
  for (const auto& e : fs::directory_iterator(dir))
    if (e.is_regular_file() && e.path().extension() == ".pcap") pcaps.push_back(e.path());
  std::sort(pcaps.begin(), pcaps.end());
  if (pcaps.empty()) throw input_error(dir.string(), "pcaps", "no .pcap files found");
  return pcaps;
}

std::vector<ScanJob> ouster_jobs(const fs::path& dir, const ImportOptions& options, ListCounts& counts) {
  std::vector<ScanJob> jobs;
  for (const auto& pcap : ouster_pcaps(dir)) {
    auto meta = std::make_shared<const OusterMetadata>(
        read_ouster_metadata(options.ouster_metadata.empty() ? ouster_metadata_for(pcap) : options.ouster_metadata));
    // Decoded once here: packets of one frame are spread over the file.
    auto frames = std::make_shared<const std::vector<OusterFrame>>(read_ouster_pcap(pcap, *meta));
    const std::string recording = pcap.stem().string();
    for (std::size_t k = 0; k < frames->size(); ++k) {
      const std::string id = std::to_string((*frames)[k].frame_id);
      jobs.push_back({"ouster/" + recording + "/" + id, {"ouster", recording, id}, pcap.string(), [meta, frames, k, pcap] {
                        const OusterFrame& f = (*frames)[k];
                        RecordedScan r{ouster_points(f, *meta), {pcap, fs::path(meta->path)}, ""};
                        if (f.valid_columns() < f.cols)
                          r.note = pcap.string() + ": frame " + std::to_string(f.frame_id) + " has " +
                                   std::to_string(f.valid_columns()) + " of " + std::to_string(f.cols) + " columns";
                        return r;
                      }});
    }
  }
  counts.found = jobs.size();
  return window(jobs, options);
}

std::vector<ScanJob> list_jobs(SourceFormat format, const fs::path& dir, const ImportOptions& options, ListCounts& counts) {
  if (options.first < 0 || options.max_frames < 0)
    throw Error("import: --first and --max-frames must be >= 0, got " + std::to_string(options.first) + " and " +
                std::to_string(options.max_frames));
  switch (format) {
    case SourceFormat::SemanticKitti: return semantickitti_jobs(dir, options, counts);
    case SourceFormat::KittiObject: return kitti_object_jobs(dir, options, counts);
    case SourceFormat::Nuscenes: return nuscenes_jobs(dir, options, counts);
    case SourceFormat::Rellis3d: return rellis3d_jobs(dir, options, counts);
    case SourceFormat::Ouster: return ouster_jobs(dir, options, counts);
  }
  throw Error("import: unknown source format");
}

pgm::BeamLayout default_layout(SourceFormat format, const fs::path& dir, const ImportOptions& options) {
  if (options.layout) {
    options.layout->validate("import: beam layout");
    check_columns(options.layout->columns);
    return *options.layout;
  }
  check_columns(options.columns);
  switch (format) {
    case SourceFormat::SemanticKitti:
    case SourceFormat::KittiObject: return pgm::BeamLayout::hdl64e(options.columns);
    case SourceFormat::Ouster: {
      const fs::path pcap = ouster_pcaps(dir).front();
      auto layout = read_ouster_metadata(options.ouster_metadata.empty() ? ouster_metadata_for(pcap) : options.ouster_metadata).layout();
      check_columns(layout.columns);
      return layout;
    }
    case SourceFormat::Nuscenes:
    case SourceFormat::Rellis3d:
      throw Error("import: " + to_string(format) + ": give the sensor's beam layout (--sensor data/sensors/...json)");
  }
  throw Error("import: unknown source format");
}

// Reads and projects the jobs a block at a time in parallel and hands each frame, in order, to
// `sink`. Errors are rethrown in job order, so the first bad file is the one reported; with
// skip_unreadable a scan whose reader fails is noted and skipped instead. Returns how many were.
template <typename Sink>
int run_jobs(const std::vector<ScanJob>& jobs, const pgm::BeamLayout& layout, const ImportOptions& o, Sink&& sink) {
  pgm::ProjectOptions po;
  po.row_mode = o.row_mode;
  po.extra_channels = o.extra_channels;
  po.min_range = o.min_range;
  const int block = o.block > 0 ? o.block : 4 * omp_get_max_threads();
  const int total = static_cast<int>(jobs.size());
  std::vector<ProjectedScan> done(block);
  std::vector<std::exception_ptr> errors(block);
  int skipped = 0;
  for (int start = 0; start < total; start += block) {
    const int count = std::min(block, total - start);
#pragma omp parallel for schedule(dynamic, 1)
    for (int i = 0; i < count; ++i) {
      try {
        const ScanJob& job = jobs[start + i];
        RecordedScan scan;
        try {
          scan = job.read();
        } catch (const Error& e) {
          if (!o.skip_unreadable) throw;
          done[i] = {};
          done[i].skipped = true;
          done[i].note = std::string("skipped unreadable scan: ") + e.what();
          continue;
        }
        auto result = pgm::project(scan.points, layout, po, job.path);
        done[i] = {std::move(result.pgm), pgm::to_string(result.row_mode), std::move(scan.sources), std::move(scan.note)};
      } catch (...) {
        errors[i] = std::current_exception();
      }
    }
    for (int i = 0; i < count; ++i) {
      if (errors[i]) std::rethrow_exception(errors[i]);
      if (!done[i].note.empty() && o.note) o.note(done[i].note);
      if (done[i].skipped) ++skipped;
      else sink(jobs[start + i], done[i]);
      done[i] = {};  // frees the grid before the next block
      if (o.progress) o.progress(start + i + 1, total);
    }
  }
  return skipped;
}

// The summary note, and an error when no listed scan could be read.
void finish_counts(const fs::path& dir, const ImportOptions& o, const ListCounts& counts, int read, int skipped) {
  note_counts(o, counts, read, skipped);
  if (read == 0) throw input_error(dir.string(), "scans", "none of the listed scans could be read");
}

}  // namespace

std::string to_string(SourceFormat format) {
  switch (format) {
    case SourceFormat::SemanticKitti: return "semantickitti";
    case SourceFormat::KittiObject: return "kitti_object";
    case SourceFormat::Nuscenes: return "nuscenes";
    case SourceFormat::Rellis3d: return "rellis3d";
    case SourceFormat::Ouster: return "ouster";
  }
  return "unknown";
}

SourceFormat source_format_from_string(const std::string& name) {
  for (SourceFormat f : {SourceFormat::SemanticKitti, SourceFormat::KittiObject, SourceFormat::Nuscenes,
                         SourceFormat::Rellis3d, SourceFormat::Ouster})
    if (to_string(f) == name) return f;
  throw Error("import: format '" + name + "': unknown (known: semantickitti, kitti_object, nuscenes, rellis3d, ouster)");
}

std::vector<std::string> dataset_channels(const ImportOptions& options) {
  std::vector<std::string> c = {"range", "class", "material"};
  for (const auto& e : options.extra_channels) {
    if (std::find(pgm::kEffectChannels.begin(), pgm::kEffectChannels.end(), e) == pgm::kEffectChannels.end()) {
      std::string known;
      for (const auto& k : pgm::kEffectChannels) known += (known.empty() ? "" : ", ") + k;
      throw Error("import: channel '" + e + "': unknown (known: " + known + ")");
    }
    if (std::find(c.begin(), c.end(), e) == c.end()) c.push_back(e);
  }
  return c;
}

ImportSummary import_to_file(SourceFormat format, const fs::path& dir, const fs::path& out, const ImportOptions& options) {
  ImportSummary summary;
  summary.layout = default_layout(format, dir, options);
  summary.channels = dataset_channels(options);
  ListCounts counts;
  const auto jobs = list_jobs(format, dir, options, counts);
  DatasetWriter writer(out, summary.channels, summary.layout, to_string(format));
  const int skipped = run_jobs(jobs, summary.layout, options, [&](const ScanJob& job, const ProjectedScan& scan) {
    writer.append(scan.pgm, job.id, scan.row_mode, job.place);
    for (const auto& s : scan.sources) writer.add_source(s.string());
  });
  finish_counts(dir, options, counts, writer.size(), skipped);
  writer.commit();
  summary.frames = writer.size();
  summary.returns = writer.returns();
  summary.row_modes = writer.row_mode_counts();
  return summary;
}

Dataset import_dataset(SourceFormat format, const fs::path& dir, const ImportOptions& options) {
  Dataset d;
  d.layout = default_layout(format, dir, options);
  d.channels = dataset_channels(options);
  d.source_format = to_string(format);
  ListCounts counts;
  const auto jobs = list_jobs(format, dir, options, counts);
  const int skipped = run_jobs(jobs, d.layout, options, [&](const ScanJob& job, const ProjectedScan& scan) {
    d.append(scan.pgm, job.id, scan.row_mode, job.place);
    for (const auto& s : scan.sources) d.sources.push_back(s.string());
  });
  finish_counts(dir, options, counts, d.size(), skipped);
  return d;
}

Dataset import_semantickitti(const fs::path& dir, const ImportOptions& options) {
  return import_dataset(SourceFormat::SemanticKitti, dir, options);
}

Dataset import_kitti_object(const fs::path& dir, const ImportOptions& options) {
  return import_dataset(SourceFormat::KittiObject, dir, options);
}

}  // namespace lidarsim::data
