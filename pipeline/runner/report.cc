// The self-contained report page (see report.h). The page is a template with two holes, the
// inlined Chart.js and the report's data as JSON; all drawing happens in the page's script.
#include "pipeline/runner/report.h"

#include "pipeline/core/capture_shape.h"

#include <opencv2/imgcodecs.hpp>  // the flags; the codecs through image_codecs.h
#include <opencv2/imgproc.hpp>

#include <filesystem>

#include "pipeline/core/atomic_file.h"
#include "pipeline/core/errors.h"
#include "pipeline/core/image_codecs.h"
#include "pipeline/core/json_file.h"
#include "pipeline/core/heldout_scores.h"
#include "pipeline/core/workspace.h"
#include "pipeline/runner/record.h"
#include "pipeline/runner/report_encoding.h"

namespace fs = std::filesystem;

namespace ibmr {

namespace {

// A PNG as a JPEG data URI no wider than `width`; "" when it cannot be read.
std::string ImageDataUri(const std::string& path, int width) {
  const cv::Mat image = DecodeImageFile(path, cv::IMREAD_COLOR);
  if (image.empty()) return "";
  return JpegDataUri(ShrinkToFit(image, width, image.rows), 82);
}

// What to do about a malformed file that stage `stage` writes.
std::string Rerun(const std::string& stage) {
  return "re-run the " + stage + " stage (ibmr run CONFIG --only " + stage + " --force)";
}

// A JSON file the page is made from; `fallback` when absent. One that is not JSON (truncated by a
// full disk or a killed copy) is an IoError naming it and `remedy`: a page that silently left it
// out looked like a run that had produced nothing.
nlohmann::json ReadReportJson(const std::string& path, nlohmann::json fallback, const std::string& remedy) {
  if (!fs::exists(path)) return fallback;
  try {
    return nlohmann::json::parse(ReadFile(path));
  } catch (const nlohmann::json::exception& e) {
    throw IoError(path + ": not valid JSON (" + e.what() + "); " + remedy);
  }
}

// Calls `read`, which takes apart the JSON of `path`; a value of another type than the code
// expects ([1] where a map belongs) becomes an IoError naming the file and `remedy`, instead of
// nlohmann's "[json.exception.type_error.306] ..." that names none.
template <typename Read>
auto ReadingFile(const std::string& path, const std::string& remedy, Read read) -> decltype(read()) {
  try {
    return read();
  } catch (const nlohmann::json::exception& e) {
    throw IoError(path + ": not the expected contents (" + e.what() + "); " + remedy);
  }
}

// The stage records of a workspace, in the order the runner wrote them (by start time).
nlohmann::json StageCosts(const Workspace& workspace) {
  std::vector<StageRecord> records;
  if (fs::is_directory(workspace.RecordsDir())) {
    for (const auto& entry : fs::directory_iterator(workspace.RecordsDir())) {
      if (entry.path().extension() != ".json") continue;
      const std::string path = entry.path().string();
      const std::string stage = entry.path().stem().string();
      // ReadRecord reads an unreadable record as "never ran", which suits the cache; the report
      // would leave the stage out without a word.
      const nlohmann::json json = ReadReportJson(path, nullptr, Rerun(stage));
      if (!json.is_object()) {
        throw IoError(path + ": not a stage record (expected a JSON object, got " + json.type_name() + "); " +
                      Rerun(stage));
      }
      records.push_back(ReadingFile(path, Rerun(stage), [&] { return StageRecord::FromJson(json); }));
    }
  }
  std::stable_sort(records.begin(), records.end(),
                   [](const StageRecord& a, const StageRecord& b) { return a.started < b.started; });
  nlohmann::json stages = nlohmann::json::array();
  for (const StageRecord& r : records) {
    stages.push_back({{"stage", r.stage},
                      {"status", r.status},
                      {"wall_seconds", r.wall_seconds},
                      {"cpu_seconds", r.cpu_seconds},
                      {"peak_memory_mb", r.peak_memory_mb},
                      {"reused", !r.reused_from.empty()},
                      {"error", r.error},
                      {"skipped_because", r.skipped_because}});
  }
  return stages;
}

// The page: styles, the containers the script fills, the inlined library and the script.
constexpr const char* kPageHead = R"HTML(<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>ibmr report</title>
<style>
body{font-family:sans-serif;margin:24px;color:#222;max-width:1500px}
h1{font-size:22px}h2{font-size:18px;margin-top:32px;border-bottom:1px solid #ccc}
table{border-collapse:collapse;font-size:13px;margin:8px 0}td,th{border:1px solid #ccc;padding:3px 8px;text-align:right}
th{background:#f0f0f0}td:first-child,th:first-child{text-align:left}tr.chosen td{background:#e6f4e6}
tr.failed td{background:#fbe3e3}.note{color:#555;font-size:13px}.charts{display:flex;flex-wrap:wrap;gap:24px}
figure{margin:8px 0}figcaption{font-size:13px;color:#444}img{max-width:100%}
#selfcheck{color:#888;font-size:11px}
</style></head><body>
<h1 id="title">ibmr report</h1><p class="note" id="subtitle"></p>
<div id="content"></div>
<pre id="selfcheck">scripts did not run</pre>
<script>
)HTML";

constexpr const char* kPageScript = R"JS(
</script>
<script>
const errors = [];
window.addEventListener('error', e => errors.push(String(e.message)));
const palette = ['#1f77b4','#d62728','#2ca02c','#ff7f0e','#9467bd','#8c564b','#e377c2','#7f7f7f','#bcbd22','#17becf',
                 '#393b79','#637939','#8c6d31','#843c39','#7b4173','#3182bd'];
const content = document.getElementById('content');
let viewerReady = null;  // the viewer's self-check word, on a workspace's page
function el(tag, attrs, parent, text) {
  const e = document.createElement(tag);
  for (const k in (attrs || {})) e.setAttribute(k, attrs[k]);
  if (text !== undefined) e.textContent = text;
  (parent || content).appendChild(e);
  return e;
}
function fmt(v, d) { return (typeof v === 'number' && isFinite(v)) ? v.toFixed(d === undefined ? 2 : d) : (v === undefined || v === null ? '' : String(v)); }
function table(parent, header, rows, rowClass) {
  const t = el('table', {}, parent);
  const h = el('tr', {}, t);
  for (const c of header) el('th', {}, h, c);
  rows.forEach((r, i) => {
    const tr = el('tr', rowClass ? {class: rowClass(i) || ''} : {}, t);
    for (const c of r) el('td', {}, tr, c);
  });
  return t;
}
function chart(parent, width, height, config) {
  const canvas = el('canvas', {width: width, height: height}, parent);
  config.options = Object.assign({animation: false, responsive: false}, config.options || {});
  try { new Chart(canvas.getContext('2d'), config); } catch (e) { errors.push('chart: ' + e.message); }
  return canvas;
}
function axis(title, extra) { return Object.assign({title: {display: true, text: title}}, extra || {}); }

function workspaceReport(R) {
  document.getElementById('title').textContent = 'ibmr report: ' + R.title;
  document.getElementById('subtitle').textContent = R.stages.length + ' stage records; held-out metric ' + R.metric;
  if (R.viewer) viewerReady = viewerSection(R.viewer, content);
  if (R.capture) {  // capture.json: the capture's kind, and what the run's plan left out for it
    const C = R.capture;
    el('h2', {}, content, 'The capture and the plan');
    el('p', {class: 'note'}, content, 'The capture is ' + C.reason + '. Silhouettes ' +
       (C.silhouettes ? 'come with the photos (alpha).' : 'do not come with the photos.') +
       (C.depth_range ? ' Depth range ' + fmt(C.depth_range[0], 3) + ' to ' + fmt(C.depth_range[1], 3) + '.' : ''));
    const skipped = R.stages.filter(s => s.status === 'skipped');
    el('p', {class: 'note'}, content, skipped.length ? skipped.length + ' stage(s) not built for this capture:' :
       'Every stage of the config serves this capture.');
    if (skipped.length) table(content, ['stage', 'why'], skipped.map(s => [s.stage, s.skipped_because.replace(s.stage + ': skipped, ', '')]));
  }
  if (R.race) {  // race.json: the models built first on a reduced copy, and what the full run left out
    const Q = R.race;
    el('h2', {}, content, 'The race: models tried small first');
    if (Q.problem) {
      el('p', {class: 'note'}, content, 'The race gave no verdict (' + Q.problem + '); every stage ran.');
    } else {
      el('p', {class: 'note'}, content, 'Every stage after the model was built at ' + Q.scale + 'x size on the training views, ' +
         Q.validation.length + ' of them held out and scored (' + Q.metric + '), in ' + fmt(Q.seconds, 1) + ' s. Best: ' + Q.best +
         '; kept: the models within ' + Q.margin_db + ' dB of it. ' + (Q.left_out.length ? Q.left_out.length +
         ' stage(s) left out of the full-size run, about ' + fmt(Q.estimated_saving_seconds, 0) + ' s saved (estimated from the race\'s times).' :
         'Nothing left out: the race cost more than it saved here.'));
      const names = Object.keys(Q.models).sort((a, b) => Q.models[b] - Q.models[a]);
      table(content, ['model', Q.metric + ' (race)', 'kept'], names.map(n => [n, fmt(Q.models[n]), Q.winners.includes(n) ? 'yes' : '']));
      if (Q.left_out.length) table(content, ['stage left out', 'its models', 'race s', 'full size s (estimate)'],
          Q.left_out.map(l => [l.stage, l.models.join(', '), fmt(l.race_seconds, 1), fmt(l.estimated_full_seconds, 0)]));
    }
  }
  el('h2', {}, content, 'Stages: time and memory');
  const stages = R.stages.filter(s => s.status !== 'skipped');
  table(content, ['stage', 'status', 'wall s', 'CPU s', 'peak MB', 'reused'],
        stages.map(s => [s.stage, s.status, fmt(s.wall_seconds), fmt(s.cpu_seconds), fmt(s.peak_memory_mb, 0), s.reused ? 'yes' : '']),
        i => stages[i].status === 'ok' ? '' : 'failed');
  const charts = el('div', {class: 'charts'});
  chart(charts, 640, 320, {type: 'bar', data: {labels: stages.map(s => s.stage), datasets: [
      {label: 'wall s', data: stages.map(s => s.wall_seconds), backgroundColor: palette[0]},
      {label: 'CPU s', data: stages.map(s => s.cpu_seconds), backgroundColor: palette[1]}]},
    options: {scales: {y: axis('seconds')}}});
  chart(charts, 640, 320, {type: 'bar', data: {labels: stages.map(s => s.stage), datasets: [
      {label: 'peak memory MB', data: stages.map(s => s.peak_memory_mb), backgroundColor: palette[2]}]},
    options: {scales: {y: axis('MB')}}});

  if (R.view_agreement) {  // multi_depth's per-view flag (dense/stereo/view_agreement.json)
    const A = R.view_agreement;
    el('h2', {}, content, 'Views that disagree with the others');
    el('p', {class: 'note'}, content, A.scored + ' views scored by their confirmed fraction (median over a view\'s neighbours ' +
       'of the share of its depth samples each confirms): median ' + fmt(A.median, 3) + ', robust scale ' + fmt(A.scale, 3) +
       '; a view is flagged ' + fmt(A.z_threshold, 1) + ' robust scales below the median (a wrong pose, or a photo the matcher fails on). ' +
       (A.flagged.length ? A.flagged.length + ' flagged (orange in the viewer):' : 'None flagged.') +
       (A.capture_poor ? ' The views agree poorly as a whole: every camera may be off alike.' : ''));
    if (A.flagged.length) table(content, ['view', 'confirmed fraction', 'z'], A.flagged.map(v => [v.name, fmt(v.figure, 3), fmt(v.z, 1)]), () => 'failed');
  }

  if (R.models.length) {
    el('h2', {}, content, 'Held-out views: scores per model');
    table(content, ['model', 'PSNR (covered)', 'SSIM', 'coverage', 'photo PSNR (holes black)', 'filled photo PSNR', 'mask PSNR'],
          R.models.map(m => [m.name, fmt(m.psnr), fmt(m.ssim, 3), fmt(m.coverage, 3), fmt(m.photo_psnr), fmt(m.filled_photo_psnr), fmt(m.mask_psnr)]));
    const c = el('div', {class: 'charts'});
    chart(c, 1000, 340, {type: 'bar', data: {labels: R.models.map(m => m.name), datasets: [
        {label: R.metric, data: R.models.map(m => m[R.metric]), backgroundColor: palette[0]},
        {label: 'psnr (covered pixels)', data: R.models.map(m => m.psnr), backgroundColor: palette[3]}]},
      options: {scales: {y: axis('dB')}}});
  }

  if (R.selection) {
    const S = R.selection;
    el('h2', {}, content, 'Model selection: how much model is enough');
    el('p', {class: 'note'}, content, 'Chosen: ' + S.chosen.name + ' (' + fmt(S.chosen.bytes, 0) + ' bytes, ' + fmt(S.chosen.psnr) +
       ' dB), the smallest within ' + fmt(S.tolerance_db) + ' dB of the best, ' + S.best.name + ' (' + fmt(S.best.bytes, 0) +
       ' bytes, ' + fmt(S.best.psnr) + ' dB): gap ' + fmt(S.gap_db) + ' dB, ' + S.metric + '.');
    table(content, ['model', 'kind', 'bytes', 'elements', S.metric, 'coverage'],
          S.models.map(m => [m.name, m.kind, fmt(m.bytes, 0), fmt(m.elements, 0), fmt(m.psnr), fmt(m.coverage, 3)]),
          i => S.models[i].name === S.chosen.name ? 'chosen' : '');
    const env = S.models.filter(m => S.envelope.includes(m.name));
    const c = el('div', {class: 'charts'});
    chart(c, 900, 400, {type: 'scatter', data: {datasets: [
        {label: 'models', data: S.models.map(m => ({x: Math.max(m.bytes, 1), y: m.psnr, name: m.name})), backgroundColor: palette[0], pointRadius: 5},
        {label: 'envelope (better than every smaller model)', data: env.map(m => ({x: Math.max(m.bytes, 1), y: m.psnr, name: m.name})),
         borderColor: palette[2], showLine: true, pointRadius: 0},
        {label: 'chosen', data: [{x: Math.max(S.chosen.bytes, 1), y: S.chosen.psnr, name: S.chosen.name}], backgroundColor: palette[1], pointRadius: 9}]},
      options: {scales: {x: axis('model size (bytes)', {type: 'logarithmic'}), y: axis(S.metric + ' (dB)')},
                plugins: {tooltip: {callbacks: {label: ctx => ctx.raw.name + ': ' + fmt(ctx.raw.y) + ' dB'}}}}});
  }

  if (R.volume_strips && R.volume_strips.length) {
    el('h2', {}, content, 'Volume of planes: each plane over a checkerboard where it is transparent, nearest first');
    for (const v of R.volume_strips) {
      const f = el('figure');
      el('figcaption', {}, f, v.folder);
      el('img', {src: v.src, alt: 'planes of ' + v.folder}, f);
    }
  }

  if (R.views.length) {
    el('h2', {}, content, 'Held-out views: photo | render | error, per model');
    for (const v of R.views) {
      el('h3', {}, content, v.view);
      for (const im of v.images) {
        const f = el('figure');
        el('figcaption', {}, f, im.model);
        el('img', {src: im.src, alt: im.model + ' ' + v.view}, f);
      }
    }
  }
}

function sweepReport(R) {
  document.getElementById('title').textContent = 'ibmr sweep: ' + R.title;
  document.getElementById('subtitle').textContent = R.variants.length + ' variants of ' + R.config + '; varied: ' +
      R.varied.join(', ') + '; held-out metric ' + R.metric;
  el('h2', {}, content, 'Speed against accuracy');
  el('p', {class: 'note'}, content, 'Each point is one model of one variant: the time to build it from scratch (the sum of its stages) ' +
     'against its held-out ' + R.metric + '. The line joins the Pareto front: nothing is both faster and better.');
  const models = [...new Set(R.points.map(p => p.model))];
  const datasets = models.map((m, i) => ({label: m, data: R.points.filter(p => p.model === m).map(p => ({x: p.seconds, y: p.psnr, v: p.variant})),
                                          backgroundColor: palette[i % palette.length], pointRadius: 5}));
  datasets.push({label: 'Pareto front', data: R.pareto.map(p => ({x: p.seconds, y: p.psnr, v: p.variant + ' ' + p.model})),
                 borderColor: '#000', showLine: true, pointRadius: 0, borderWidth: 1});
  const c = el('div', {class: 'charts'});
  chart(c, 1000, 460, {type: 'scatter', data: {datasets: datasets},
    options: {scales: {x: axis('seconds (all stages)'), y: axis(R.metric + ' (dB)')},
              plugins: {tooltip: {callbacks: {label: ctx => ctx.raw.v + ': ' + fmt(ctx.raw.x, 1) + ' s, ' + fmt(ctx.raw.y) + ' dB'}}}}});
  table(content, ['variant', 'model', 'seconds', R.metric], R.pareto.map(p => [p.variant, p.model, fmt(p.seconds, 1), fmt(p.psnr)]));

  el('h2', {}, content, 'Time per stage per variant');
  const stageNames = [...new Set(R.variants.flatMap(v => v.stages.map(s => s.stage)))];
  chart(content, 1000, 380, {type: 'bar', data: {labels: R.variants.map(v => v.name), datasets: stageNames.map((s, i) => ({
      label: s, backgroundColor: palette[i % palette.length],
      data: R.variants.map(v => { const st = v.stages.find(x => x.stage === s); return st ? st.wall_seconds || 0 : 0; })}))},
    options: {scales: {x: {stacked: true}, y: axis('seconds', {stacked: true})}}});

  el('h2', {}, content, 'Variants');
  const allModels = [...new Set(R.variants.flatMap(v => Object.keys(v.models)))];
  table(content, ['variant', 'parameters', 'status', 'seconds', 'computed here', 'peak MB'].concat(allModels.map(m => m + ' ' + R.metric)),
        R.variants.map(v => [v.name, v.label, v.status, fmt(v.wall_seconds, 1), fmt(v.computed_wall_seconds, 1), fmt(v.peak_memory_mb, 0)]
                             .concat(allModels.map(m => v.models[m] ? fmt(v.models[m][R.metric]) : ''))),
        i => R.variants[i].status === 'ok' ? '' : 'failed');

  if (R.stability && R.stability.length) {
    // One line chart per curve: strengths along x, a series per method.
    const strengthCharts = (curves) => {
      const box = el('div', {class: 'charts'});
      for (const curve of curves) {
        chart(box, 480, 300, {type: 'line', data: {labels: curve.strengths.map(x => String(x)), datasets: curve.series.map((d, i) => ({
            label: d.label, data: d.values, borderColor: palette[i % palette.length], backgroundColor: palette[i % palette.length]}))},
          options: {plugins: {title: {display: true, text: curve.title}}, scales: {x: axis(curve.axis), y: axis(curve.value)}}});
      }
    };
    el('h2', {}, content, 'Stability: error against the strength of each degradation');
    strengthCharts(R.stability);
    if (R.stability_sparsification && R.stability_sparsification.length) {
      el('h3', {}, content, 'Confidence: area under the sparsification curve over the optimal one (1: the confidence orders the errors perfectly)');
      strengthCharts(R.stability_sparsification);
    }
    el('h3', {}, content, 'Where each method breaks (quality below 0.8 of the clean scene) and its confidence there');
    table(content, ['degradation', 'method', 'breaks at strength', 'confidence-error rho there', 'sparsification AUC / optimal there'],
          R.stability_breaks.map(b => [b.degradation, b.method, b.breaks_at === null ? 'holds' : fmt(b.breaks_at), fmt(b.confidence_rho_at_break),
                                       fmt(b.sparsification_auc_ratio_at_break)]));
    for (const d of (R.stability_detectors || [])) {
      const rows = d.cells.filter(c => c.precision !== null || c.recall !== null || c.false_calls !== null);
      if (!rows.length) continue;
      el('h3', {}, content, d.name + ': precision (of the views it called out, how many were wrong) and recall (of the wrong views, how many it called out), per cell');
      table(content, ['degradation', 'strength', 'precision', 'recall', 'false calls'],
            rows.map(c => [c.degradation, fmt(c.strength), fmt(c.precision, 2), fmt(c.recall, 2), fmt(c.false_calls, 0)]),
            i => rows[i].false_calls > 0 ? 'failed' : '');
    }
    el('h3', {}, content, 'Every cell: value, relative quality, confidence-error rank correlation (negative: confidence falls where error rises), sparsification AUC over the optimal');
    table(content, ['degradation', 'strength', 'method', 'value', 'relative', 'rho', 'AUC / optimal', 'why it produced nothing'],
          R.stability_cells.map(c => [c.degradation, fmt(c.strength), c.method, fmt(c.value, 4), fmt(c.relative, 3), fmt(c.confidence_rho, 3),
                                      fmt(c.sparsification_auc_ratio, 3), c.why || '']),
          i => R.stability_cells[i].failed ? 'failed' : '');
  }
}

try {
  if (REPORT.kind === 'sweep') sweepReport(REPORT); else workspaceReport(REPORT);
} catch (e) { errors.push(e.message); }

setTimeout(async () => {
  let viewer = '';
  if (viewerReady) {
    try { viewer = ' viewer=' + await viewerReady; } catch (e) { errors.push('viewer: ' + e.message); viewer = ' viewer=error'; }
  }
  const canvases = [...document.querySelectorAll('canvas:not(.viewer)')];
  let drawn = 0;
  for (const c of canvases) {
    const data = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
    let painted = 0;
    for (let i = 3; i < data.length && painted <= 100; i += 4) if (data[i] !== 0) ++painted;
    if (painted > 100) ++drawn;
  }
  document.getElementById('selfcheck').textContent = 'charts=' + canvases.length + ' drawn=' + drawn + ' errors=' + errors.length +
      viewer + (errors.length ? ' ' + errors.join(' | ') : '');
}, 0);
</script></body></html>
)JS";

// Text safe inside a <script> element: "</" cannot close it early.
std::string ScriptSafe(std::string text) {
  for (size_t at = text.find("</"); at != std::string::npos; at = text.find("</", at + 3)) text.replace(at, 2, "<\\/");
  return text;
}

// The held-out scores of scores/heldout.json into the report's models and views.
void GatherScores(const Workspace& workspace, const nlohmann::json& scores, int image_width, nlohmann::json* report) {
  nlohmann::json models = nlohmann::json::array();
  nlohmann::json views = nlohmann::json::array();
  const nlohmann::json proxies = scores.value("proxies", nlohmann::json::object());
  std::map<std::string, nlohmann::json> images_by_view;
  for (const auto& [name, proxy] : proxies.items()) {
    nlohmann::json model = HeldoutMeans(proxy);
    if (model.empty()) continue;
    model["name"] = name;
    models.push_back(model);
    const nlohmann::json per_view = proxy.value("views", nlohmann::json::object());
    for (const auto& [view, entry] : per_view.items()) {
      const std::string side_by_side = workspace.Path("scores/" + name + "/" + fs::path(view).stem().string() + ".png");
      const std::string uri = ImageDataUri(side_by_side, image_width);
      if (uri.empty()) continue;
      images_by_view[view].push_back({{"model", name}, {"src", uri}});
    }
  }
  for (const auto& [view, images] : images_by_view) views.push_back({{"view", view}, {"images", images}});
  (*report)["models"] = models;
  (*report)["views"] = views;
}

// dense/stereo/view_agreement.json (pipeline/core/view_agreement.h) for the page: the capture's
// figures and the flagged views with their figure and z.
nlohmann::json ViewAgreementSummary(const nlohmann::json& agreement) {
  nlohmann::json flagged = nlohmann::json::array();
  for (const auto& view : agreement.at("views")) {
    if (!view.value("flagged", false)) continue;
    flagged.push_back({{"name", view.at("name")}, {"figure", view.at("figure")}, {"z", view.at("z")}});
  }
  return {{"scored", agreement.value("scored", 0)},
          {"median", agreement.value("median", 0.0)},
          {"scale", agreement.value("scale", 0.0)},
          {"z_threshold", agreement.value("z_threshold", 0.0)},
          {"capture_poor", agreement.value("capture_poor", false)},
          {"flagged", flagged}};
}

// The page's data from sweep.json's contents.
nlohmann::json SweepReport(const std::string& folder, const nlohmann::json& sweep) {
  nlohmann::json report = {{"kind", "sweep"},
                           {"title", folder},
                           {"config", sweep.value("config", "")},
                           {"metric", sweep.value("metric", "psnr")},
                           {"varied", sweep.value("varied", nlohmann::json::array())},
                           {"points", sweep.value("points", nlohmann::json::array())},
                           {"pareto", sweep.value("pareto", nlohmann::json::array())},
                           {"variants", sweep.value("variants", nlohmann::json::array())},
                           {"stability", nlohmann::json::array()},
                           {"stability_breaks", nlohmann::json::array()},
                           {"stability_cells", nlohmann::json::array()},
                           {"stability_sparsification", nlohmann::json::array()},
                           {"stability_detectors", nlohmann::json::array()}};
  if (sweep.contains("stability") && sweep["stability"].is_object()) {
    report["stability"] = sweep["stability"].value("curves", nlohmann::json::array());
    report["stability_breaks"] = sweep["stability"].value("breaks", nlohmann::json::array());
    report["stability_cells"] = sweep["stability"].value("cells", nlohmann::json::array());
    report["stability_sparsification"] = sweep["stability"].value("sparsification_curves", nlohmann::json::array());
    report["stability_detectors"] = sweep["stability"].value("detectors", nlohmann::json::array());
  }
  // The page needs only the costs and scores, not every stage's metrics.
  for (auto& variant : report["variants"]) {
    for (auto& stage : variant["stages"]) stage.erase("metrics");
  }
  return report;
}

}  // namespace

nlohmann::json GatherWorkspaceReport(const std::string& root, int image_width, nlohmann::json* scores_out) {
  const Workspace workspace(root);
  nlohmann::json report = {{"kind", "workspace"}, {"title", root}, {"stages", StageCosts(workspace)}};
  const std::string selection_path = workspace.Path("scores/selection.json");
  const nlohmann::json selection = ReadReportJson(selection_path, nullptr, Rerun("select"));
  report["selection"] = selection;
  report["metric"] = ReadingFile(selection_path, Rerun("select"), [&]() -> nlohmann::json {
    return selection.is_object() ? selection.value("metric", "photo_psnr") : "photo_psnr";
  });
  const std::string scores_path = workspace.Path("scores/heldout.json");
  const nlohmann::json scores = ReadReportJson(scores_path, nlohmann::json::object(), Rerun("score"));
  ReadingFile(scores_path, Rerun("score"), [&] { GatherScores(workspace, scores, image_width, &report); });
  if (scores_out != nullptr) *scores_out = scores;
  // The volume stage's plane strips (volume/<reference>/strip.png), at twice the views' width.
  nlohmann::json strips = nlohmann::json::array();
  std::vector<fs::path> strip_paths;
  std::error_code ec;
  for (fs::directory_iterator it(workspace.Path("volume"), ec), end; !ec && it != end; it.increment(ec)) {
    if (fs::exists(it->path() / "strip.png")) strip_paths.push_back(it->path() / "strip.png");
  }
  std::sort(strip_paths.begin(), strip_paths.end());
  for (const fs::path& path : strip_paths) {
    const std::string uri = ImageDataUri(path.string(), 2 * image_width);
    if (!uri.empty()) strips.push_back({{"folder", workspace.Relative(path.parent_path().string())}, {"src", uri}});
  }
  report["volume_strips"] = strips;
  // The capture's kind and figures (the runner's plan, issue 66), once poses existed.
  const std::string capture_path = workspace.Path(kCaptureFile);
  const nlohmann::json capture = ReadReportJson(capture_path, nlohmann::json(), "run the config again (ibmr run)");
  if (capture.is_object() && capture.contains("kind") && capture["kind"].is_string()) report["capture"] = capture;
  const std::string race_path = workspace.Path("race.json");
  const nlohmann::json race = ReadReportJson(race_path, nlohmann::json(), "run the config again (ibmr run)");
  if (race.is_object() && race.contains("validation")) {
    nlohmann::json page = race;
    for (const char* key : {"models", "winners", "left_out"}) {
      if (!page.contains(key)) page[key] = key == std::string("models") ? nlohmann::json::object() : nlohmann::json::array();
    }
    report["race"] = page;
  }
  // multi_depth's per-view agreement and flags (issue 67), when it ran.
  const std::string agreement_path = workspace.ViewAgreementPath();
  const nlohmann::json agreement = ReadJsonOr(agreement_path, nlohmann::json());
  if (agreement.is_object()) {
    ReadingFile(agreement_path, Rerun("multi_depth"), [&] { report["view_agreement"] = ViewAgreementSummary(agreement); });
  }
  return report;
}

nlohmann::json GatherSweepReport(const std::string& folder) {
  const std::string path = folder + "/sweep.json";
  const std::string remedy = "run the sweep again (ibmr sweep CONFIG --out " + folder + ")";
  const nlohmann::json sweep = ReadReportJson(path, nlohmann::json::object(), remedy);
  if (!sweep.is_object()) {
    throw IoError(path + ": expected a JSON object, got " + std::string(sweep.type_name()) + "; " + remedy);
  }
  return ReadingFile(path, remedy, [&] { return SweepReport(folder, sweep); });
}

std::string WriteReport(const ReportOptions& options) {
  const bool is_sweep = fs::exists(options.path + "/sweep.json");
  if (!is_sweep && !fs::is_directory(options.path + "/records")) {
    throw InputError(options.path + " holds neither sweep.json (an ibmr sweep folder) nor records/ (a workspace); "
                     "give a workspace or a sweep folder");
  }
  if (!fs::exists(options.chart_js)) {
    throw InputError(options.chart_js + " is missing: the report inlines Chart.js from Debian's libjs-chart.js "
                     "(apt-get install libjs-chart.js, or scripts/setup.sh)");
  }
  std::string invalid;
  if (!options.viewer.Check(&invalid)) throw InputError(invalid);
  nlohmann::json scores;
  nlohmann::json data = is_sweep ? GatherSweepReport(options.path)
                                 : GatherWorkspaceReport(options.path, options.image_width, &scores);
  ViewerData viewer;
  if (!is_sweep) {
    const std::string metric = data["metric"].is_string() ? data["metric"].get<std::string>() : "photo_psnr";
    viewer = GatherViewer(options.path, scores, metric, options.viewer);
    data["viewer"] = viewer.viewer;
  }
  std::string page = kPageHead;
  page += ScriptSafe(ReadFile(options.chart_js));
  // three.js and its orbit controls for the viewer; without them the page says what to install.
  if (!is_sweep && fs::exists(options.three_js) && fs::exists(options.orbit_controls_js)) {
    page += "\n</script>\n<script>\n" + ScriptSafe(ReadFile(options.three_js));
    page += "\n</script>\n<script>\n" + ScriptSafe(ReadFile(options.orbit_controls_js));
  }
  page += "\n</script>\n" + ViewerArraysHtml(viewer) + "<script>\n" + std::string(kViewerScript);
  page += "\n</script>\n<script>\nconst REPORT = ";
  page += ScriptSafe(DumpJson(data));
  page += ";";
  page += kPageScript;
  const std::string out = options.out.empty() ? options.path + "/report/index.html" : options.out;
  WriteFileAtomic(out, page);
  return out;
}

}  // namespace ibmr
