// Parallel loops on a caller-sized TBB arena: parallelism is passed in,
// never a hidden global. With one thread the loop runs inline (serial path).
#pragma once

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <memory>

namespace craftscan {

class Parallel {
 public:
  explicit Parallel(int num_threads) : num_threads_(num_threads < 1 ? 1 : num_threads) {
    if (num_threads_ > 1) arena_ = std::make_unique<tbb::task_arena>(num_threads_);
  }
  int num_threads() const { return num_threads_; }

  // Calls fn(i0, i1) on disjoint chunks covering [begin, end). Each index is
  // processed exactly once; callers make each index's work independent of
  // the others so that results do not depend on the thread count.
  template <class Fn>
  void For(int begin, int end, Fn&& fn, int grain = 1) const {
    if (end <= begin) return;
    if (!arena_ || end - begin == 1) {
      fn(begin, end);
      return;
    }
    arena_->execute([&] {
      tbb::parallel_for(tbb::blocked_range<int>(begin, end, grain),
                        [&](const tbb::blocked_range<int>& r) { fn(r.begin(), r.end()); });
    });
  }

 private:
  int num_threads_;
  std::unique_ptr<tbb::task_arena> arena_;
};

}  // namespace craftscan
