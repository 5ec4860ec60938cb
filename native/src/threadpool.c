/* A small persistent thread pool: workers wait between jobs and take chunks of a job through an
 * atomic counter, so load balances itself. Results never depend on which thread ran a chunk;
 * callers make every chunk's output independent of the thread. One job runs at a time (a mutex
 * serialises concurrent callers, e.g. two Python threads that both released the GIL).
 *
 * A training step runs some 25 jobs, often a fraction of a millisecond apart, and a render a
 * dozen: waking sleeping workers for each (a futex wake per worker, each then queueing for the
 * pool's lock, a virtual CPU brought back by its hypervisor) and putting the caller to sleep
 * until the last one is done cost tens of microseconds per job, more the more threads there
 * are, all of it serial. So a job is published through one atomic word (its sequence number
 * and thread count) that workers watch, spinning for SPIN_MS after their last job before they
 * sleep on a condition variable; workers count down an atomic when done, and the caller spins
 * for the same time before it sleeps. Nobody spins when a job's threads outnumber the cores. The lock is taken only to wake sleepers or be woken.
 * POSIX threads, or Win32 threads on Windows, behind a few wrappers. */
#if !defined(_WIN32)
#define _GNU_SOURCE /* sched_getaffinity, CPU_COUNT */
#endif
#include "internal.h"

#include <stdatomic.h>
#include <time.h>

#if defined(__x86_64__) || defined(_M_X64) || defined(__i386__)
#include <immintrin.h>
static void cpu_relax(void) { _mm_pause(); }
#elif defined(__aarch64__) && defined(__GNUC__)
static void cpu_relax(void) { __asm__ __volatile__("yield"); }
#else
static void cpu_relax(void) {}
#endif

#if defined(_WIN32)
#define WIN32_LEAN_AND_MEAN
#include <windows.h>

typedef SRWLOCK sc_mutex;
typedef CONDITION_VARIABLE sc_cond;
#define SC_MUTEX_INIT SRWLOCK_INIT
#define SC_COND_INIT CONDITION_VARIABLE_INIT
static void mutex_lock(sc_mutex *m) { AcquireSRWLockExclusive(m); }
static void mutex_unlock(sc_mutex *m) { ReleaseSRWLockExclusive(m); }
static void cond_wait(sc_cond *c, sc_mutex *m) { SleepConditionVariableSRW(c, m, INFINITE, 0); }
static void cond_signal(sc_cond *c) { WakeConditionVariable(c); }
static void cond_broadcast(sc_cond *c) { WakeAllConditionVariable(c); }

static DWORD WINAPI worker_entry(LPVOID arg);
/* Start a detached worker; 0 on success. */
static int start_worker(int id) {
    HANDLE h = CreateThread(NULL, 0, worker_entry, (LPVOID)(intptr_t)id, 0, NULL);
    if (!h) return -1;
    CloseHandle(h);
    return 0;
}

int sc_cpu_count(void) {
    /* All processor groups (machines with more than 64 logical processors have several). */
    DWORD n = GetActiveProcessorCount(ALL_PROCESSOR_GROUPS);
    return n > 0 ? (int)n : 1;
}

static double wall_ms(void) {
    LARGE_INTEGER f, t;
    QueryPerformanceFrequency(&f);
    QueryPerformanceCounter(&t);
    return 1000.0 * (double)t.QuadPart / (double)f.QuadPart;
}

/* (GetThreadTimes counts in 100 ns units, but may advance only every timer tick.) */
static double thread_cpu_ms(void) {
    FILETIME created, exited, kernel, user;
    if (!GetThreadTimes(GetCurrentThread(), &created, &exited, &kernel, &user)) return wall_ms();
    const ULONGLONG k = ((ULONGLONG)kernel.dwHighDateTime << 32) | kernel.dwLowDateTime;
    const ULONGLONG u = ((ULONGLONG)user.dwHighDateTime << 32) | user.dwLowDateTime;
    return 1e-4 * (double)(k + u);
}

#else
#include <pthread.h>
#include <sched.h>
#include <unistd.h>

typedef pthread_mutex_t sc_mutex;
typedef pthread_cond_t sc_cond;
#define SC_MUTEX_INIT PTHREAD_MUTEX_INITIALIZER
#define SC_COND_INIT PTHREAD_COND_INITIALIZER
static void mutex_lock(sc_mutex *m) { pthread_mutex_lock(m); }
static void mutex_unlock(sc_mutex *m) { pthread_mutex_unlock(m); }
static void cond_wait(sc_cond *c, sc_mutex *m) { pthread_cond_wait(c, m); }
static void cond_signal(sc_cond *c) { pthread_cond_signal(c); }
static void cond_broadcast(sc_cond *c) { pthread_cond_broadcast(c); }

static void *worker_entry(void *arg);
static int start_worker(int id) {
    pthread_t thread;
    if (pthread_create(&thread, NULL, worker_entry, (void *)(intptr_t)id) != 0) return -1;
    pthread_detach(thread);
    return 0;
}

int sc_cpu_count(void) {
#ifdef CPU_COUNT
    cpu_set_t set;
    if (sched_getaffinity(0, sizeof set, &set) == 0) return CPU_COUNT(&set);
#endif
    long n = sysconf(_SC_NPROCESSORS_ONLN);
    return n > 0 ? (int)n : 1;
}

static double wall_ms(void) {
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return 1000.0 * (double)t.tv_sec + 1e-6 * (double)t.tv_nsec;
}

static double thread_cpu_ms(void) {
    struct timespec t;
    if (clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t) != 0) return wall_ms();
    return 1000.0 * (double)t.tv_sec + 1e-6 * (double)t.tv_nsec;
}
#endif

/* Profiling (sc_pool_profile): off unless a benchmark asks, and then process-wide. Times in
 * nanoseconds, so that threads add to them atomically. */
static struct {
    atomic_int on, cpu_clock;
    atomic_llong jobs, inside_ns, busy_ns, offered_ns;
} profile;

/* The stages' clock: wall time, or while a one-thread profile asks for it the calling thread's
 * CPU time (which a busy machine's other processes do not inflate). */
double sc_now_ms(void) {
    return atomic_load_explicit(&profile.cpu_clock, memory_order_relaxed) ? thread_cpu_ms()
                                                                           : wall_ms();
}

enum { MAX_WORKERS = 255, PARTICIPANTS_BITS = 16 };
/* How long a worker watches for the next job, and the caller for the last worker, before they
 * sleep: longer than the gaps inside a step (a Python call between two kernels), short
 * enough that an idle pool costs nothing to speak of. */
static const double SPIN_MS = 0.05;

static struct {
    sc_mutex job_lock;    /* one job at a time */
    sc_mutex lock;        /* sleeping and waking */
    sc_cond wake, finished;
    int started;          /* workers created so far */
    /* The job: sequence number << PARTICIPANTS_BITS | threads taking part (the caller and
     * workers 1 .. participants - 1), stored (release) once the fields below are set. */
    atomic_ullong job;
    atomic_int busy;      /* participating workers not yet done */
    int sleepers;         /* workers asleep on `wake` (under lock) */
    int caller_asleep;    /* the caller asleep on `finished` (under lock) */
    sc_task fn;
    void *ctx;
    int64_t n, grain;
    atomic_llong next;
} pool = {.job_lock = SC_MUTEX_INIT, .lock = SC_MUTEX_INIT, .wake = SC_COND_INIT,
          .finished = SC_COND_INIT};

static int64_t ms_to_ns(double ms) { return (int64_t)(ms * 1e6); }

static void run_chunks(int thread) {
    const int profiling = atomic_load_explicit(&profile.on, memory_order_relaxed);
    const double start = profiling ? sc_now_ms() : 0.0;
    for (;;) {
        int64_t begin = atomic_fetch_add(&pool.next, pool.grain);
        if (begin >= pool.n) break;
        int64_t end = begin + pool.grain < pool.n ? begin + pool.grain : pool.n;
        pool.fn(pool.ctx, begin, end, thread);
    }
    if (profiling) atomic_fetch_add(&profile.busy_ns, ms_to_ns(sc_now_ms() - start));
}

/* Whether a job on `threads` threads may spin: not when they outnumber the cores, where a
 * spinning thread would take a core from one with work. */
static int may_spin(int threads) {
    static atomic_int cores;
    int n = atomic_load_explicit(&cores, memory_order_relaxed);
    if (n == 0) atomic_store_explicit(&cores, n = sc_cpu_count(), memory_order_relaxed);
    return threads <= n;
}

/* The next job after `seen`: watched for SPIN_MS, then slept for. */
static uint64_t next_job(uint64_t seen) {
    const int spin = may_spin((int)(seen & ((1u << PARTICIPANTS_BITS) - 1)));
    const double until = wall_ms() + SPIN_MS;
    for (unsigned i = 1; spin; ++i) {
        const uint64_t job = atomic_load_explicit(&pool.job, memory_order_acquire);
        if (job != seen) return job;
        if (i % 64 == 0 && wall_ms() > until) break;
        cpu_relax();
    }
    mutex_lock(&pool.lock);
    pool.sleepers++;
    uint64_t job;
    while ((job = atomic_load_explicit(&pool.job, memory_order_acquire)) == seen)
        cond_wait(&pool.wake, &pool.lock);
    pool.sleepers--;
    mutex_unlock(&pool.lock);
    return job;
}

static void worker_main(int id) {
    uint64_t seen = 0;
    for (;;) {
        seen = next_job(seen);
        if (id >= (int)(seen & ((1u << PARTICIPANTS_BITS) - 1))) continue; /* not in this one */
        run_chunks(id);
        /* The caller cannot publish another job before this, so the fields read were this job's. */
        if (atomic_fetch_sub_explicit(&pool.busy, 1, memory_order_acq_rel) == 1) {
            mutex_lock(&pool.lock);
            if (pool.caller_asleep) cond_signal(&pool.finished);
            mutex_unlock(&pool.lock);
        }
    }
}

#if defined(_WIN32)
static DWORD WINAPI worker_entry(LPVOID arg) {
    worker_main((int)(intptr_t)arg);
    return 0;
}
#else
static void *worker_entry(void *arg) {
    worker_main((int)(intptr_t)arg);
    return NULL;
}
#endif

/* A job's wall time, counted when profiling: inside, and offered to each of its threads. */
static void note_job(double start, int threads) {
    const int64_t ns = ms_to_ns(sc_now_ms() - start);
    atomic_fetch_add(&profile.jobs, 1);
    atomic_fetch_add(&profile.inside_ns, ns);
    atomic_fetch_add(&profile.offered_ns, ns * threads);
}

static void parallel_for(int threads, int64_t n, int64_t grain, sc_task fn, void *ctx);

void sc_parallel_for(int threads, int64_t n, int64_t grain, sc_task fn, void *ctx) {
    if (n <= 0) return;
    if (grain < 1) grain = 1;
    int64_t chunks = (n + grain - 1) / grain;
    if (threads > chunks) threads = (int)chunks;
    if (threads > MAX_WORKERS + 1) threads = MAX_WORKERS + 1;
    if (threads < 1) threads = 1;
    if (!atomic_load_explicit(&profile.on, memory_order_relaxed)) {
        parallel_for(threads, n, grain, fn, ctx);
        return;
    }
    const double start = sc_now_ms();
    parallel_for(threads, n, grain, fn, ctx);
    note_job(start, threads);
}

double sc_pool_inside_ms(void) {
    return atomic_load_explicit(&profile.on, memory_order_relaxed)
               ? 1e-6 * (double)atomic_load(&profile.inside_ns)
               : 0.0;
}

void sc_pool_profile(int mode, sc_pool_counters *taken) {
    taken->jobs = atomic_exchange(&profile.jobs, 0);
    taken->inside_ms = 1e-6 * (double)atomic_exchange(&profile.inside_ns, 0);
    taken->busy_ms = 1e-6 * (double)atomic_exchange(&profile.busy_ns, 0);
    taken->offered_ms = 1e-6 * (double)atomic_exchange(&profile.offered_ns, 0);
    atomic_store(&profile.cpu_clock, mode == SC_PROFILE_CPU);
    atomic_store(&profile.on, mode != SC_PROFILE_OFF);
}

/* sc_parallel_for with its arguments settled (1 <= threads <= chunks). */
static void parallel_for(int threads, int64_t n, int64_t grain, sc_task fn, void *ctx) {
    if (threads <= 1) {
        const int profiling = atomic_load_explicit(&profile.on, memory_order_relaxed);
        const double start = profiling ? sc_now_ms() : 0.0;
        fn(ctx, 0, n, 0);
        if (profiling) atomic_fetch_add(&profile.busy_ns, ms_to_ns(sc_now_ms() - start));
        return;
    }
    mutex_lock(&pool.job_lock);
    /* Worker ids start at 1; the caller is thread 0. A failed start just means fewer helpers:
     * the caller still runs every chunk that nobody else takes. */
    while (pool.started < threads - 1 && start_worker(pool.started + 1) == 0) pool.started++;
    const int helpers = threads - 1 < pool.started ? threads - 1 : pool.started;
    pool.fn = fn;
    pool.ctx = ctx;
    pool.n = n;
    pool.grain = grain;
    atomic_store_explicit(&pool.next, 0, memory_order_relaxed);
    atomic_store_explicit(&pool.busy, helpers, memory_order_relaxed);
    const uint64_t sequence = (atomic_load_explicit(&pool.job, memory_order_relaxed) >>
                               PARTICIPANTS_BITS) + 1;
    atomic_store_explicit(&pool.job, sequence << PARTICIPANTS_BITS | (uint64_t)(helpers + 1),
                          memory_order_release);
    mutex_lock(&pool.lock);
    if (pool.sleepers) cond_broadcast(&pool.wake);
    mutex_unlock(&pool.lock);

    run_chunks(0);

    const double until = may_spin(helpers + 1) ? wall_ms() + SPIN_MS : 0.0;
    for (unsigned i = 1; atomic_load_explicit(&pool.busy, memory_order_acquire) > 0; ++i) {
        if (i % 64 == 1 && wall_ms() > until) {
            mutex_lock(&pool.lock);
            pool.caller_asleep = 1;
            while (atomic_load_explicit(&pool.busy, memory_order_acquire) > 0)
                cond_wait(&pool.finished, &pool.lock);
            pool.caller_asleep = 0;
            mutex_unlock(&pool.lock);
            break;
        }
        cpu_relax();
    }
    mutex_unlock(&pool.job_lock);
}
