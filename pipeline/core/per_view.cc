// Parallel per-view loop with resumption and shards (see per_view.h).
#include "pipeline/core/per_view.h"

#include <spdlog/spdlog.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_for_each.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <atomic>
#include <mutex>

#include "pipeline/core/errors.h"
#include "pipeline/core/process_memory.h"

namespace ibmr {

PerViewSummary ForEachView(StageContext& context, const std::string& phase, const std::vector<std::string>& views,
                           const std::function<nlohmann::json(const std::string& view)>& work) {
  const bool shard = !context.shard_views.empty();
  if (shard) {
    std::string unknown;
    for (const std::string& view : context.shard_views) {
      if (std::find(views.begin(), views.end(), view) == views.end()) unknown += (unknown.empty() ? "" : ", ") + view;
    }
    if (!unknown.empty()) {
      throw InputError("--views: not among this stage's " + std::to_string(views.size()) + " views: " + unknown +
                       " (`ibmr views CONFIG STAGE` lists them)");
    }
  }
  std::vector<std::string> todo;
  PerViewSummary summary;
  for (const std::string& view : views) {
    if (shard && !context.shard_views.count(view)) continue;
    if (std::optional<nlohmann::json> piece = context.checkpoint.Piece(view)) {
      ++summary.resumed;
      summary.pieces[view] = std::move(*piece);
    } else {
      todo.push_back(view);
    }
  }
  NullProgress null_progress;
  ProgressReporter* progress = context.progress ? context.progress : &null_progress;
  progress->Begin(phase, summary.resumed + todo.size());
  if (summary.resumed > 0) progress->Advance(summary.resumed, "(done by an earlier run)");
  std::mutex mutex;
  auto run_one = [&](const std::string& view) {
    // A failure names its view (for a cluster job, the line the user reads first).
    auto named = [&](const std::exception& e) {
      const std::string message = e.what();
      return message.find(view) == std::string::npos ? message + " [view " + view + "]" : message;
    };
    nlohmann::json piece;
    try {
      piece = work(view);
    } catch (const InputError& e) {
      throw InputError(named(e));
    } catch (const IoError& e) {
      throw IoError(named(e));
    }
    context.checkpoint.MarkDone(view, piece);
    progress->Advance(1, view);
    std::lock_guard<std::mutex> lock(mutex);
    summary.pieces[view] = std::move(piece);
  };
  // What the stage loaded before this loop counts against the budget: refit the views in
  // flight to the memory left now (the full-size castle's render holds its 20 M depth splats
  // before it renders a view).
  if (context.view_memory_mb > 0 && !todo.empty()) {
    const int threads = tbb::this_task_arena::max_concurrency();
    const double remaining = RemainingMemoryMb(context.memory_limit_mb);
    const int fit = std::clamp(static_cast<int>(remaining / context.view_memory_mb), 1, threads);
    const int before = context.max_views_in_flight > 0 ? context.max_views_in_flight : threads;
    if (fit < before) {
      spdlog::info("{}: {} view(s) at a time: {:.0f} MB left, about {:.0f} MB per view", phase, fit, remaining,
                   context.view_memory_mb);
      context.max_views_in_flight = fit;
    }
  }
  const int slots = context.max_views_in_flight;
  if (slots <= 0 || slots >= tbb::this_task_arena::max_concurrency()) {
    tbb::parallel_for_each(todo.begin(), todo.end(), run_one);
  } else {
    // `slots` views at a time (memory): each slot takes the next view when its last is done, and
    // the threads without a slot help inside the views' own parallel loops.
    std::atomic<size_t> next{0};
    std::atomic<bool> failed{false};
    tbb::parallel_for(0, slots, [&](int) {
      for (size_t i = next++; i < todo.size() && !failed; i = next++) {
        try {
          run_one(todo[i]);
        } catch (...) {
          failed = true;
          throw;
        }
      }
    });
  }
  progress->End();
  summary.computed = todo.size();
  context.views_resumed += summary.resumed;
  if (shard) throw ShardFinished{summary.computed, summary.resumed};
  return summary;
}

}  // namespace ibmr
