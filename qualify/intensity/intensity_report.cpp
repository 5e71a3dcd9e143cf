// The intensity loop's JSON, written from the typed round result (intensity_internal.h).
#include "common/error.h"
#include "qualify/intensity/intensity_internal.h"

namespace lidarsim::qualify {

IntensityBase parse_intensity_base(const std::string& name, const std::string& option) {
  if (name == "unet") return IntensityBase::Unet;
  if (name == "lookup") return IntensityBase::Lookup;
  if (name == "lookup-beam") return IntensityBase::LookupBeam;
  throw Error("loop intensity: " + option + " \"" + name + "\": unknown (expected unet, lookup or lookup-beam)");
}

std::string to_string(IntensityBase base) {
  switch (base) {
    case IntensityBase::Unet: return "unet";
    case IntensityBase::Lookup: return "lookup";
    case IntensityBase::LookupBeam: return "lookup-beam";
  }
  return "?";
}

}  // namespace lidarsim::qualify

namespace lidarsim::qualify::intensity_detail {

namespace {

std::string base_text(const IntensityLoopOptions& o) {
  switch (o.base_model) {
    case Base::Unet:
      return "UNet (base " + std::to_string(o.unet.base) + ", depth " + std::to_string(o.unet.depth) +
             ") on range, class, material, trained " + std::to_string(o.unet.steps) +
             " steps on each fold's fit sectors; mean of " + std::to_string(o.unet.seeds) + " seeds" +
             (o.unet.lookup_base ? "; learning the residual over the class x 5 m range + per-beam lookup" : "");
    case Base::Lookup: return "class x 5 m range-bin lookup fitted on each fold's fit sectors";
    case Base::LookupBeam:
      return "class x 5 m range-bin lookup + per-beam offsets (lidar-train --lookup-base=classes) fitted on each "
             "fold's fit sectors";
  }
  return "";
}

nlohmann::json scores(const std::vector<FeatureScore>& list, const std::vector<std::string>* forms,
                      const std::vector<double>* maes) {
  nlohmann::json a = nlohmann::json::array();
  for (size_t k = 0; k < list.size(); ++k) {
    nlohmann::json e = {{"feature", list[k].feature}, {"score", list[k].score}, {"interval95", list[k].interval}};
    if (forms) e["form"] = (*forms)[k], e["held_out_mae_after"] = (*maes)[k];
    a.push_back(e);
  }
  return a;
}

nlohmann::json candidate_json(const Candidate& k) {
  const bool window = k.form == Form::Window || k.form == Form::WindowGain;
  nlohmann::json j = {{"feature", k.feature},
          {"form", k.name()},
          {"effect_size", k.score.effect},
          {"held_out_r2", k.score.r2},
          {"interval95", k.score.interval},
          {"significant", k.score.interval[0] > 0},
          {"held_out_mae_after", k.score.mae_after},
          {"edges", window ? nlohmann::json(k.score.shown.table.edges) : nlohmann::json(nullptr)},
          {"decision", decision_name(k.decision)},
          {"reason", k.reason}};
  // held_out_r2 is then the lower of this and the score across classes x row blocks.
  if (k.scenery_checked) j["held_out_r2_column_groups"] = k.column_r2;
  return j;
}

}  // namespace

nlohmann::json to_json(const RoundResult& r, const IntensityLoopOptions& o) {
  const bool unet = o.base_model == Base::Unet;
  nlohmann::json j;
  j["domain"] = "intensity";
  j["metric"] = "held-out MAE of intensity (validation regions of the split, every scan; pooled over the folds)";
  j["split"] = r.split;
  j["validation_folds"] = r.folds;  // not "folds": the object loop's list of sequence folds
  j["cross_fit"] = "candidate forms fitted on the pooled held-out residual of the other groups, by " + r.group_by;
  if (!r.azimuth_group_by.empty())
    j["azimuth_cross_fit"] = "azimuth forms fitted on the pooled held-out residual by " + r.azimuth_group_by;
  j["scenery_correlation_between_scans"] = r.scenery_correlation;
  j["scenery_correlation_between_time_blocks"] = r.time_block_correlation;
  j["receptive_field_half_width"] = r.half_width;
  j["base_model"] = base_text(o);
  j["before"] = r.before.mae;
  j["after"] = r.after.mae;
  j["rmse_before"] = r.before.rmse;
  j["rmse_after"] = r.after.rmse;
  j["change_interval95"] = r.added ? nlohmann::json::array({r.interval[0], r.interval[1]}) : nlohmann::json::array({0.0, 0.0});
  j["held_out_cells"] = r.before.n;
  j["lookup_before"] = r.lookup_before;
  if (unet) {
    j["seeds_before"] = r.seeds_before;
    j["seeds_after"] = r.seeds_after;
    j["training"] = {{"base", o.unet.base},   {"depth", o.unet.depth},
                     {"steps", o.unet.steps}, {"batch", o.unet.batch},
                     {"crop_columns", o.unet.crop_columns}, {"lr", o.unet.lr},
                     {"lambda", o.unet.lambda}, {"seeds", o.unet.seeds}};
  }
  j["ranking"] = scores(r.ranking, &r.ranking_form, &r.ranking_mae);
  j["used_by_model"] = scores(r.used, nullptr, nullptr);
  j["undecided"] = scores(r.undecided, nullptr, nullptr);
  nlohmann::json all = nlohmann::json::array();
  for (const Candidate& k : r.candidates) all.push_back(candidate_json(k));
  j["candidates_tested"] = all;
  j["top_form"] = r.top_form;
  j["added_effect"] = r.added ? nlohmann::json(r.top_feature) : nlohmann::json(nullptr);
  j["method"] = r.added ? r.method : "none";
  if (r.candidate && !r.added)
    j["rejected_effect"] = {{"feature", r.top_feature},
                            {"method", r.method},
                            {"held_out_after", r.tried.mae},
                            {"change_interval95", {r.interval[0], r.interval[1]}},
                            {"seeds", unet ? nlohmann::json(r.seeds_tried) : nlohmann::json(nullptr)},
                            {"why", r.rejected_why}};
  if (!r.not_tried_why.empty()) j["top_not_tried"] = r.not_tried_why;
  nlohmann::json refits = nlohmann::json::object();
  for (const Refit& f : r.refits) refits[f.method] = f.mae;
  j["candidates_held_out_mae"] = refits;
  j["threshold"] = o.threshold;
  j["min_relative_gain"] = o.min_relative_gain;
  j["score_definition"] =
      std::string("held-out R^2 of the correction a form implies (additive, gain or affine table over 16 "
                  "equal-count bins or one bin per beam row, or a window; tables shrunk by n/(n+5); for beam_row and "
                  "elevation also a range slope per bin, measured ~ base exp(a + s ln range)) on the residual "
                  "measured - ") +
      (unet ? "UNet" : "base") +
      " pooled over the folds' held-out cells, winsorised at its 1st/99th percentile, each form fitted on the other "
      "cross-fit groups; interval95 = basic block bootstrap over 16-column blocks (all scans of a block together). "
      "The top feature is refitted when its score is at least the threshold, and added when the refit lowers the "
      "pooled held-out MAE by at least min_relative_gain with a block-bootstrap 95% interval of the change below 0";
  if (r.added && r.effect_table.ok())
    j["effect"] = {{"feature", r.top_feature},
                   {"form", form_name(r.effect_table.form, r.top_feature == "beam_row")},
                   {"edges", r.effect_table.table.edges},
                   {"table", r.effect_table.table.value},
                   {"slope", r.effect_table.slope},
                   {"centre", r.effect_table.centre},
                   {"residual_table", r.residual_tables.count(r.top_feature)
                                          ? nlohmann::json(r.residual_tables.at(r.top_feature).value)
                                          : nlohmann::json(nullptr)}};
  if (!r.plot.empty()) j["plot"] = r.plot;
  if (unet && !o.out_model.empty()) j["model"] = o.out_model.string();
  return j;
}

nlohmann::json round_summary(const nlohmann::json& r) {
  return nlohmann::json{{"added_effect", r["added_effect"]}, {"method", r["method"]},
                        {"top", r["ranking"].empty() ? nlohmann::json(nullptr) : r["ranking"][0]},
                        {"before", r["before"]}, {"after", r["after"]},
                        {"change_interval95", r["change_interval95"]},
                        {"rejected_effect", r.contains("rejected_effect") ? r["rejected_effect"] : nlohmann::json(nullptr)}};
}

}  // namespace lidarsim::qualify::intensity_detail
