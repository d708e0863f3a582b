// How craftscan's processes ask glibc to keep memory they free.
//
// By default glibc serves a block above a threshold (128 kB at first,
// raised by itself up to 32 MB as blocks are freed) straight from the
// kernel with mmap and unmaps it when freed, and gives the top of its heap
// back above 128 kB. A matcher that allocates and frees the same few
// megabytes for every view (OpenCV's temporaries, per-call buffers) then
// has those pages faulted in afresh each time: about 15 µs a 4 kB page on
// this project's VM, up to ~1 900 faults (28 ms) a 1280×1024 station view,
// depending on the order in which glibc raised its threshold (README 11.4,
// stop 55). Which of the two a run got showed as a bimodal match time.
#pragma once

namespace craftscan {

// Fixes the mmap threshold at 32 MB (glibc's largest) and trims the heaps
// only above 256 MB, so freed blocks are reused rather than returned:
// memory that was once in use stays with the process (its peak RSS is the
// same). For processes that match views over and over (craftscand,
// craftscan-worker, craftscan-bench); call it first thing in main(). Leaves
// the allocator alone where the environment already tunes it
// (MALLOC_MMAP_THRESHOLD_, MALLOC_TRIM_THRESHOLD_, GLIBC_TUNABLES) and off
// glibc. Returns whether the policy is in effect.
bool KeepFreedMemory();

}  // namespace craftscan
