// Buffers of hundreds of megabytes (cost volumes, semi-global sums) that are filled right after
// they are sized: `LargeBuffer<T>` is a std::vector whose allocator
//  * leaves new elements uninitialised (default-initialised, as `new T[n]` would), where
//    std::vector's resize writes zeros the caller overwrites at once: a 300 MB cost volume costs a
//    memset per first use;
//  * asks the kernel for transparent huge pages (madvise MADV_HUGEPAGE) on blocks of 2 MB and
//    more, aligned to 2 MB: a first touch then faults one 2 MB page instead of 512 small ones.
//    Linux's default THP mode ("madvise") gives huge pages only to memory that asks.
// On templeSparseRing's plane sweep (bench_plane_sweep: 16 views, two sets of 1.2 GB buffers
// first touched) the stage took 3.65-3.69 s before and 2.5-3.0 s after (the huge pages alone, as
// glibc's glibc.malloc.hugetlb=1 tunable gives them, which a program cannot set for itself:
// 3.15-3.24 s). The depth maps are identical.
// Contents after resize are unspecified: the caller assigns every element it reads.
#pragma once

#include <sys/mman.h>

#include <cstddef>
#include <cstdlib>
#include <new>
#include <type_traits>
#include <utility>
#include <vector>

namespace ibmr {

template <class T>
struct LargeBufferAllocator {
  using value_type = T;
  static constexpr size_t kHugePage = size_t{2} << 20;

  LargeBufferAllocator() = default;
  template <class U>
  LargeBufferAllocator(const LargeBufferAllocator<U>&) noexcept {}  // NOLINT: allocators convert implicitly

  T* allocate(size_t n) {
    const size_t bytes = n * sizeof(T);
    if (bytes < kHugePage) {
      void* p = std::malloc(bytes == 0 ? 1 : bytes);
      if (p == nullptr) throw std::bad_alloc();
      return static_cast<T*>(p);
    }
    void* p = nullptr;
    const size_t rounded = (bytes + kHugePage - 1) / kHugePage * kHugePage;
    if (posix_memalign(&p, kHugePage, rounded) != 0) throw std::bad_alloc();
    madvise(p, rounded, MADV_HUGEPAGE);  // advice only: without THP the pages are small ones
    return static_cast<T*>(p);
  }
  void deallocate(T* p, size_t) noexcept { std::free(p); }

  // Value-less construction leaves trivial elements uninitialised; anything else as usual.
  template <class U>
  void construct(U* p) noexcept(std::is_nothrow_default_constructible_v<U>) {
    ::new (static_cast<void*>(p)) U;
  }
  template <class U, class... Args>
  void construct(U* p, Args&&... args) {
    ::new (static_cast<void*>(p)) U(std::forward<Args>(args)...);
  }

  template <class U>
  bool operator==(const LargeBufferAllocator<U>&) const noexcept { return true; }
  template <class U>
  bool operator!=(const LargeBufferAllocator<U>&) const noexcept { return false; }
};

template <class T>
using LargeBuffer = std::vector<T, LargeBufferAllocator<T>>;

}  // namespace ibmr
