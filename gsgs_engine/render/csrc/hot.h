// GSGS_HOT: hot loops get an AVX2 clone next to the portable one (runtime dispatch through an ifunc),
// so a cached build stays valid on any x86-64 machine: no -march=native. Lambdas handed to
// at::parallel_for are not cloned with their caller, so the cloned code lives in named functions.
#pragma once

#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && defined(__linux__)
#define GSGS_HOT __attribute__((target_clones("avx2", "default")))
#else
#define GSGS_HOT
#endif
