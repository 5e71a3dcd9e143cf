// The box index of the KITTI object reader against the rule it replaces (each point against
// each box, first box in file order wins), and its cost on a label file far beyond real scenes.
#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <random>

#include "data/kitti_object.h"
#include "data/velodyne.h"
#include "pgm/materials.h"
#include "tests/data/temp_dir.h"
#include "tests/support/shared_data.h"

using namespace lidarsim;
using lidarsim::testing::TempDir;

namespace {

// The oracle: every point against every box in file order, first hit wins.
std::vector<std::size_t> label_every_box(std::vector<pgm::Point>& points, const data::KittiCalib& calib,
                                         const std::vector<data::KittiObjectLabel>& labels) {
  std::vector<std::size_t> counts(labels.size(), 0);
  for (auto& p : points) {
    p.class_id = pgm::cls::unlabeled;
    p.material_id = pgm::material::unknown;
    const Eigen::Vector3d rect = calib.velo_to_rect({p.x, p.y, p.z});
    for (std::size_t k = 0; k < labels.size(); ++k) {
      if (labels[k].type == "DontCare" || !labels[k].contains_rect(rect)) continue;
      p.class_id = pgm::class_from_object_type(labels[k].type);
      p.material_id = pgm::default_material(p.class_id);
      ++counts[k];
      break;
    }
  }
  return counts;
}

// Same classes, materials and per-box counts as the oracle; returns the points inside boxes.
std::size_t expect_same_as_every_box(const std::vector<pgm::Point>& points, const data::KittiCalib& calib,
                                     const std::vector<data::KittiObjectLabel>& labels, const std::string& what) {
  std::vector<pgm::Point> indexed = points, oracle = points;
  const auto got = data::label_points_from_boxes(indexed, calib, labels);
  const auto want = label_every_box(oracle, calib, labels);
  EXPECT_EQ(got, want) << what;
  std::size_t differ = 0, inside = 0;
  for (std::size_t i = 0; i < points.size(); ++i) {
    differ += indexed[i].class_id != oracle[i].class_id || indexed[i].material_id != oracle[i].material_id;
    inside += oracle[i].class_id != pgm::cls::unlabeled;
  }
  EXPECT_EQ(differ, 0u) << what;
  return inside;
}

// KITTI's camera axes from the Velodyne's: x right = -y, y down = -z, z forward = x.
data::KittiCalib upright_calib() {
  data::KittiCalib c;
  c.Tr_velo_to_cam << 0, -1, 0, 0, 0, 0, -1, 0, 1, 0, 0, 0;
  return c;
}

const char* kTypes[] = {"Car", "Pedestrian", "Cyclist", "Van", "Truck", "Misc"};

void write_label_line(std::ostream& out, const char* type, double h, double w, double l, double x, double y, double z, double ry) {
  out << type << " 0 0 0 0 0 10 10 " << h << " " << w << " " << l << " " << x << " " << y << " " << z << " " << ry << "\n";
}

}  // namespace

TEST(KittiObjectReal, BoxIndexLabelsEveryPointAsTestingEveryBox) {
  for (const char* sub : {"kitti-object-sample", "kitti-object-more"}) {
    LIDARSIM_REQUIRE_SHARED_DATA(dir, sub);
    std::size_t inside = 0;
    for (const auto& f : data::list_kitti_object(dir)) {
      const auto points = data::read_velodyne_bin(f.bin);
      inside += expect_same_as_every_box(points, data::read_kitti_calib(f.calib), data::read_kitti_object_labels(f.label),
                                         f.label.string());
    }
    EXPECT_GT(inside, 1000u) << sub;  // the comparison covers labelled points, not only background
  }
}

// Overlapping rotated boxes of every class and points packed around and on their faces: where
// several boxes hold a point, the first in the file must still win.
TEST(KittiObject, BoxIndexKeepsFileOrderWhereBoxesOverlap) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(0, 1);
  std::vector<data::KittiObjectLabel> labels;
  for (int k = 0; k < 400; ++k) {
    data::KittiObjectLabel o;
    o.type = k % 17 == 0 ? "DontCare" : kTypes[k % 6];
    o.h = 0.5 + 2 * u(rng), o.w = 0.3 + 3 * u(rng), o.l = 0.3 + 8 * u(rng);
    o.location = {-10 + 20 * u(rng), 1.7, 5 + 20 * u(rng)};
    o.rotation_y = -M_PI + 2 * M_PI * u(rng);
    labels.push_back(o);
  }
  labels[5].l = 60, labels[5].w = 40;  // one oversized box over most of the others
  const auto calib = upright_calib();
  std::vector<pgm::Point> points;
  for (int i = 0; i < 40000; ++i)
    points.push_back({static_cast<float>(4 + 22 * u(rng)), static_cast<float>(-11 + 22 * u(rng)),
                      static_cast<float>(-1.8 + 2.4 * u(rng))});
  for (const auto& o : labels)  // on the corners of each footprint (rounding decides)
    for (double sx : {-0.5, 0.5})
      for (double sz : {-0.5, 0.5}) {
        const double c = std::cos(o.rotation_y), s = std::sin(o.rotation_y);
        const double ax = sx * o.l, az = sz * o.w;
        const Eigen::Vector3d rect(o.location.x() + c * ax + s * az, o.location.y() - o.h / 2, o.location.z() - s * ax + c * az);
        const Eigen::Vector3d v = calib.rect_to_velo(rect);
        points.push_back({static_cast<float>(v.x()), static_cast<float>(v.y()), static_cast<float>(v.z())});
      }
  EXPECT_GT(expect_same_as_every_box(points, calib, labels, "synthetic"), 10000u);
}

// 10,000 boxes over a 100 m square and a frame of 120,000 points: testing each point against
// each box took 22.8 s; the index must stay far below 2 s on a slow CPU. The file also gets
// the warning naming it and its count.
TEST(KittiObject, TenThousandBoxesImportInSecondsWithAWarning) {
  TempDir dir;
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> u(0, 1);
  for (const char* sub : {"velodyne", "label_2", "calib"}) std::filesystem::create_directories(dir / sub);
  {
    std::ofstream label(dir / "label_2/000000.txt");
    for (int k = 0; k < 10000; ++k)
      write_label_line(label, kTypes[k % 6], 1.5, 1.5 + u(rng), 2 + 3 * u(rng), -50 + 100 * u(rng), 1.7, 100 * u(rng),
                       -M_PI + 2 * M_PI * u(rng));
    std::ofstream(dir / "calib/000000.txt") << "R0_rect: 1 0 0 0 1 0 0 0 1\nTr_velo_to_cam: 0 -1 0 0 0 0 -1 0 1 0 0 0\n";
    std::vector<float> xyzr;
    for (int i = 0; i < 120000; ++i)
      for (double v : {100 * u(rng), -50 + 100 * u(rng), -1.7 + 1.8 * u(rng), u(rng)}) xyzr.push_back(static_cast<float>(v));
    std::ofstream(dir / "velodyne/000000.bin", std::ios::binary)
        .write(reinterpret_cast<const char*>(xyzr.data()), static_cast<std::streamsize>(xyzr.size() * sizeof(float)));
  }
  const auto frames = data::list_kitti_object(dir.path());
  ASSERT_EQ(frames.size(), 1u);
  ::testing::internal::CaptureStderr();
  const auto t0 = std::chrono::steady_clock::now();
  const auto scan = data::read_kitti_object_scan(frames[0]);
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  const std::string err = ::testing::internal::GetCapturedStderr();
  std::printf("10,000 boxes, 120,000 points: %.3f s\n", seconds);
  EXPECT_LT(seconds, 2.0);
  EXPECT_NE(err.find("warning: " + frames[0].label.string() + ": 10000 objects"), std::string::npos) << err;
  std::size_t inside = 0;
  for (auto n : scan.points_in_box) inside += n;
  EXPECT_GT(inside, 10000u);  // the boxes do hold points: the index is not skipping them
}

TEST(KittiObject, WarnsAboveTheObjectCountOfRealScenesOnly) {
  TempDir dir;
  for (std::size_t n : {data::kManyKittiObjects, data::kManyKittiObjects + 1}) {
    const auto path = dir / ("l" + std::to_string(n) + ".txt");
    {
      std::ofstream out(path);
      for (std::size_t k = 0; k < n; ++k) write_label_line(out, "Car", 1.5, 1.6, 4, 0, 1.7, 10, 0);
    }
    ::testing::internal::CaptureStderr();
    EXPECT_EQ(data::read_kitti_object_labels(path).size(), n);
    const std::string err = ::testing::internal::GetCapturedStderr();
    if (n > data::kManyKittiObjects)
      EXPECT_NE(err.find(path.string() + ": " + std::to_string(n) + " objects"), std::string::npos) << err;
    else
      EXPECT_EQ(err, "");
  }
}
