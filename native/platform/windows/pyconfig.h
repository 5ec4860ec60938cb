/* pyconfig.h for cross-compiling splatcore for 64-bit Windows (zig cc, mingw-w64 headers, UCRT)
 * against CPython 3.11's limited API (abi3). scripts/build_native.py copies the host's Python
 * 3.11 headers and puts this file in place of their (Linux) pyconfig.h: the limited-API headers
 * read only what is defined here, taken from CPython's PC/pyconfig.h for MS_WIN64. What
 * matters most: LLP64 sizes (long is 4 bytes), wchar_t is 2 bytes, and Py_ENABLE_SHARED +
 * HAVE_DECLSPEC_DLL so the API is declared __declspec(dllimport) (from python3.dll) and
 * PyInit_splatcore __declspec(dllexport). */
#ifndef Py_CONFIG_H
#define Py_CONFIG_H

#if !defined(_WIN64) || !defined(__x86_64__)
#error "this pyconfig.h is for 64-bit x86 Windows targets only"
#endif

#define MS_WIN32
#define MS_WIN64
#define MS_WINDOWS
#define NT_THREADS
#define WITH_THREAD
#define Py_ENABLE_SHARED 1
#define HAVE_DECLSPEC_DLL
#define PLATFORM "win32"

typedef long long Py_ssize_t;
#define HAVE_PY_SSIZE_T 1

#define SIZEOF_SHORT 2
#define SIZEOF_INT 4
#define SIZEOF_LONG 4
#define SIZEOF_LONG_LONG 8
#define SIZEOF_DOUBLE 8
#define SIZEOF_FLOAT 4
#define SIZEOF_VOID_P 8
#define SIZEOF_SIZE_T 8
#define SIZEOF_UINTPTR_T 8
#define SIZEOF_TIME_T 8
#define SIZEOF_FPOS_T 8
#define SIZEOF_WCHAR_T 2
#define SIZEOF__BOOL 1
#define HAVE_LONG_LONG 1
#define HAVE_WCHAR_H 1
#define HAVE_USABLE_WCHAR_T 1
#define DOUBLE_IS_LITTLE_ENDIAN_IEEE754 1

#endif
