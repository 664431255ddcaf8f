// Preloaded (LD_PRELOAD) into one rank by view_over_ranks.sh to fail one allocation on purpose:
// after SIGUSR1, the next operator new of at least $ADAPTISO_TEST_FAIL_NEW_BYTES bytes throws
// std::bad_alloc, once. Rank 0 then fails to take a rank's answer, as a machine short of memory
// would; the answers after it must still be the ones asked for (they once came one behind).
#include <atomic>
#include <csignal>
#include <cstdint>
#include <cstdlib>
#include <new>

#include <unistd.h>

namespace {

std::atomic<bool> armed{false};

std::size_t threshold() {
  static const std::size_t bytes = [] {
    const char* v = std::getenv("ADAPTISO_TEST_FAIL_NEW_BYTES");
    return v ? static_cast<std::size_t>(std::strtoull(v, nullptr, 10)) : SIZE_MAX;
  }();
  return bytes;
}

__attribute__((constructor)) void arm_on_sigusr1() {
  std::signal(SIGUSR1, [](int) { armed.store(true); });
}

}  // namespace

void* operator new(std::size_t n) {
  if (n >= threshold() && armed.exchange(false)) {
    static const char said[] = "fail_alloc_shim: failed an allocation\n";  // the test checks it fired
    (void)!write(2, said, sizeof said - 1);
    throw std::bad_alloc();
  }
  if (void* p = std::malloc(n ? n : 1)) return p;
  throw std::bad_alloc();
}
void* operator new[](std::size_t n) { return operator new(n); }
void operator delete(void* p) noexcept { std::free(p); }
void operator delete[](void* p) noexcept { std::free(p); }
void operator delete(void* p, std::size_t) noexcept { std::free(p); }
void operator delete[](void* p, std::size_t) noexcept { std::free(p); }
