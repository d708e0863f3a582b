// KeepFreedMemory (memory_policy.h): a block freed and allocated again is
// reused, not faulted in afresh. Without the policy glibc unmaps an 8 MB
// block when it is freed and the next one faults in all its 2 048 pages.
#include <sys/resource.h>

#include <cstdlib>

#include <gtest/gtest.h>

#include "craftscan/pipeline/common/memory_policy.h"

namespace craftscan {
namespace {

long MinorFaults() {
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  return usage.ru_minflt;
}

// Allocates `bytes`, writes one byte a page, frees; the page faults taken.
long FaultsOfOneUse(std::size_t bytes) {
  const long before = MinorFaults();
  volatile char* p = static_cast<volatile char*>(std::malloc(bytes));
  if (p == nullptr) return -1;
  for (std::size_t i = 0; i < bytes; i += 4096) p[i] = 1;
  std::free(const_cast<char*>(p));
  return MinorFaults() - before;
}

TEST(MemoryPolicy, AFreedBlockIsReusedWithoutPageFaults) {
  if (!KeepFreedMemory())
    GTEST_SKIP() << "not glibc's allocator (a sanitizer's?) or tuned by the environment";
  constexpr std::size_t kBytes = 8 << 20;  // 2 048 pages
  ASSERT_GE(FaultsOfOneUse(kBytes), 0);    // the first use may fault every page
  const long again = FaultsOfOneUse(kBytes);
  EXPECT_GE(again, 0);
  EXPECT_LT(again, 64) << "the freed block was given back and faulted in again";
}

}  // namespace
}  // namespace craftscan
