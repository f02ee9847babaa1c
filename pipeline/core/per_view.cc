// Parallel per-view loop with resumption (see per_view.h).
#include "pipeline/core/per_view.h"

#include <tbb/parallel_for_each.h>

#include <atomic>

namespace ibmr {

PerViewSummary ForEachView(StageContext& context, const std::string& phase, const std::vector<std::string>& views,
                           const std::function<void(const std::string& view)>& work) {
  std::vector<std::string> todo;
  PerViewSummary summary;
  for (const std::string& view : views) {
    if (context.checkpoint.Done(view)) {
      ++summary.resumed;
    } else {
      todo.push_back(view);
    }
  }
  NullProgress null_progress;
  ProgressReporter* progress = context.progress ? context.progress : &null_progress;
  progress->Begin(phase, views.size());
  if (summary.resumed > 0) progress->Advance(summary.resumed, "(done by an earlier run)");
  tbb::parallel_for_each(todo.begin(), todo.end(), [&](const std::string& view) {
    work(view);
    context.checkpoint.MarkDone(view);
    progress->Advance(1, view);
  });
  progress->End();
  summary.computed = todo.size();
  return summary;
}

}  // namespace ibmr
