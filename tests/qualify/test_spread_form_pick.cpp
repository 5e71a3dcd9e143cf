// Which spread form the object loop adds once one has cleared the selection-aware bound
// (qualify/objects/object_spread_forms.h best_form_of_picked): the best-scoring form of the same
// feature and target whose own interval lies above 0, not necessarily the one that cleared the bound.
#include <gtest/gtest.h>

#include <algorithm>
#include <iterator>
#include <vector>

#include "qualify/objects/object_candidates.h"
#include "qualify/objects/object_spread_forms.h"

using namespace lidarsim::qualify;
using namespace lidarsim::qualify::obj;

namespace {

int sfp_target(const char* name) {
  return static_cast<int>(std::find(kObjectTargets.begin(), kObjectTargets.end(), name) - kObjectTargets.begin());
}

Candidate sfp_candidate(Kind kind, const char* feature, const char* target, double score, double lo, double hi,
                        double bound) {
  Candidate c;
  c.kind = kind;
  c.feature = feature_index(feature);
  c.target = sfp_target(target);
  c.score = score;
  c.interval = {lo, hi};
  c.selection_lower = bound;
  return c;
}

}  // namespace

// The numbers of a speed spread on the error across (campaign seed 1, draw 9): the table clears the
// bound over the 240 spread forms, the line scores higher held out but its wider interval fails
// the bound. The line is added; forms of other features, targets or fold sets, forms whose own
// interval reaches 0 and forms below the threshold never are.
TEST(SpreadFormPick, BestScoringFormOfTheFeatureThatClearedTheBound) {
  std::vector<Candidate> c = {
      sfp_candidate(Kind::SpreadTable, "speed", "position_across", 0.206, 0.171, 0.246, 0.140),
      sfp_candidate(Kind::SpreadLine, "speed", "position_across", 0.237, 0.111, 0.488, -0.159),
      sfp_candidate(Kind::SpreadWindow, "speed", "position_across", 0.136, 0.099, 0.176, 0.068),
  };
  EXPECT_EQ(best_form_of_picked(c, 0, 0.05), 1);

  // Not a better form: its interval reaches 0, it is below the threshold, or it is another feature,
  // target or fold set (each scoring above the table).
  std::vector<Candidate> d = c;
  d[1].interval[0] = -0.01;
  EXPECT_EQ(best_form_of_picked(d, 0, 0.05), 0);
  EXPECT_EQ(best_form_of_picked(c, 0, 0.30), 0);  // every other form below this threshold
  d = c;
  d[1].feature = feature_index("radial_velocity");
  EXPECT_EQ(best_form_of_picked(d, 0, 0.05), 0);
  d = c;
  d[1].target = sfp_target("position_along");
  EXPECT_EQ(best_form_of_picked(d, 0, 0.05), 0);
  d = c;
  d[1].fold_set = 1;
  EXPECT_EQ(best_form_of_picked(d, 0, 0.05), 0);
  d = c;
  d[1].kind = Kind::MeanLine;  // a bias form is never a spread form
  EXPECT_EQ(best_form_of_picked(d, 0, 0.05), 0);
  // The best of several: the highest score wins, and the picked form stays when it is the best.
  c.push_back(sfp_candidate(Kind::SpreadGrowth, "speed", "position_across", 0.30, 0.05, 0.55, -0.2));
  EXPECT_EQ(best_form_of_picked(c, 0, 0.05), 3);
  EXPECT_EQ(best_form_of_picked(c, 3, 0.05), 3);
}
