#pragma once
// SFGS_HD marks a function that the CPU backends and the CUDA kernels share: host and device under nvcc, a plain
// inline function in a C++ compiler.
#if defined(__CUDACC__)
#define SFGS_HD __host__ __device__ __forceinline__
#else
#define SFGS_HD inline
#endif
