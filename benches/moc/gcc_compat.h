// Force-included (g++ -include) before each of MOC's files: GCC 11 and later
// define __cpuidex (cpuid.h) and _xgetbv (immintrin.h) themselves, which
// MOC's CompilerSpecific.inl defines again for g++. The system headers are
// read first here (their include guards keep them from being read again);
// MOC's definitions and calls are then renamed, so they no longer clash.
#pragma once
#include <cpuid.h>
#include <immintrin.h>
#define __cpuidex moc_cpuidex
#define _xgetbv moc_xgetbv
