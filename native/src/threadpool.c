/* A small persistent thread pool: workers sleep on a condition variable between jobs and take
 * chunks of a job through an atomic counter, so load balances itself. Results never depend on
 * which thread ran a chunk; callers make every chunk's output independent of the thread.
 * One job runs at a time (a mutex serialises concurrent callers, e.g. two Python threads that
 * both released the GIL). Without pthreads (Windows builds) jobs run on the calling thread. */
#if !defined(_WIN32)
#define _GNU_SOURCE /* sched_getaffinity, CPU_COUNT */
#endif
#include "internal.h"

#include <stdatomic.h>
#include <time.h>

#if defined(_WIN32)
#include <windows.h>

int sc_cpu_count(void) {
    SYSTEM_INFO info;
    GetSystemInfo(&info);
    return (int)info.dwNumberOfProcessors;
}

void sc_parallel_for(int threads, int64_t n, int64_t grain, sc_task fn, void *ctx) {
    (void)threads;
    (void)grain;
    if (n > 0) fn(ctx, 0, n, 0);
}

double sc_now_ms(void) {
    LARGE_INTEGER f, t;
    QueryPerformanceFrequency(&f);
    QueryPerformanceCounter(&t);
    return 1000.0 * (double)t.QuadPart / (double)f.QuadPart;
}

#else
#include <pthread.h>
#include <sched.h>
#include <stdlib.h>
#include <unistd.h>

enum { MAX_WORKERS = 255 };

static struct {
    pthread_mutex_t job_lock; /* one job at a time */
    pthread_mutex_t lock;
    pthread_cond_t wake, finished;
    pthread_t workers[MAX_WORKERS];
    int started;      /* workers created so far */
    uint64_t epoch;   /* bumped for every job */
    int participants; /* workers (ids 1..participants-1) taking part in this job */
    int busy;         /* participating workers not yet done */
    sc_task fn;
    void *ctx;
    int64_t n, grain;
    atomic_llong next;
} pool = {.job_lock = PTHREAD_MUTEX_INITIALIZER,
          .lock = PTHREAD_MUTEX_INITIALIZER,
          .wake = PTHREAD_COND_INITIALIZER,
          .finished = PTHREAD_COND_INITIALIZER};

int sc_cpu_count(void) {
#ifdef CPU_COUNT
    cpu_set_t set;
    if (sched_getaffinity(0, sizeof set, &set) == 0) return CPU_COUNT(&set);
#endif
    long n = sysconf(_SC_NPROCESSORS_ONLN);
    return n > 0 ? (int)n : 1;
}

double sc_now_ms(void) {
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return 1000.0 * (double)t.tv_sec + 1e-6 * (double)t.tv_nsec;
}

static void run_chunks(int thread) {
    for (;;) {
        int64_t begin = atomic_fetch_add(&pool.next, pool.grain);
        if (begin >= pool.n) break;
        int64_t end = begin + pool.grain < pool.n ? begin + pool.grain : pool.n;
        pool.fn(pool.ctx, begin, end, thread);
    }
}

static void *worker_main(void *arg) {
    int id = (int)(intptr_t)arg;
    uint64_t seen = 0;
    pthread_mutex_lock(&pool.lock);
    for (;;) {
        while (pool.epoch == seen) pthread_cond_wait(&pool.wake, &pool.lock);
        seen = pool.epoch;
        if (id >= pool.participants) continue;
        pthread_mutex_unlock(&pool.lock);
        run_chunks(id);
        pthread_mutex_lock(&pool.lock);
        if (--pool.busy == 0) pthread_cond_signal(&pool.finished);
    }
    return NULL;
}

void sc_parallel_for(int threads, int64_t n, int64_t grain, sc_task fn, void *ctx) {
    if (n <= 0) return;
    if (grain < 1) grain = 1;
    int64_t chunks = (n + grain - 1) / grain;
    if (threads > chunks) threads = (int)chunks;
    if (threads > MAX_WORKERS + 1) threads = MAX_WORKERS + 1;
    if (threads <= 1) {
        fn(ctx, 0, n, 0);
        return;
    }
    pthread_mutex_lock(&pool.job_lock);
    pthread_mutex_lock(&pool.lock);
    while (pool.started < threads - 1) {
        /* Worker ids start at 1; the caller is thread 0. A failed start just means fewer
         * helpers: the caller still runs every chunk that nobody else takes. */
        if (pthread_create(&pool.workers[pool.started], NULL, worker_main,
                           (void *)(intptr_t)(pool.started + 1)) != 0)
            break;
        pthread_detach(pool.workers[pool.started]);
        pool.started++;
    }
    int helpers = threads - 1 < pool.started ? threads - 1 : pool.started;
    pool.fn = fn;
    pool.ctx = ctx;
    pool.n = n;
    pool.grain = grain;
    atomic_store(&pool.next, 0);
    pool.participants = helpers + 1;
    pool.busy = helpers;
    pool.epoch++;
    pthread_cond_broadcast(&pool.wake);
    pthread_mutex_unlock(&pool.lock);

    run_chunks(0);

    pthread_mutex_lock(&pool.lock);
    while (pool.busy > 0) pthread_cond_wait(&pool.finished, &pool.lock);
    pthread_mutex_unlock(&pool.lock);
    pthread_mutex_unlock(&pool.job_lock);
}
#endif
