/* The k nearest neighbours of every point among the others (sc_neighbours, splatcore.h), by a
 * k-d tree: the index array is split at the median of the widest coordinate of each range, down
 * to leaves of a few points (the tree is implicit: a node is its index range, its children the
 * two halves; only each node's split axis and value are stored), then each point descends to
 * its own side first and visits a far side only when the splitting plane is no farther than
 * its k-th best so far. Splits follow the data, so a capture's dense surfaces and far-flung
 * outliers cost about the same per point (a uniform grid over the bounding box put a hundred
 * points in a cell of a normal cloud's core: 10 s for a million points).
 *
 * Distances are squared, in double, from the float32 coordinates; ties go to the lower index,
 * so the result is one well-defined list (the brute-force reference in
 * tests/reference_deform.py gives the same). Rest positions of a deformed splat object are what
 * this runs on (addon/core/deform/neighbours.py). */
#include <stdlib.h>

#include "internal.h"

enum { GRAIN = 2048, LEAF = 8 };

typedef struct {
    const float *points;
    int32_t *index; /* permuted: each node's points are index[lo .. hi) */
    uint8_t *axis;  /* per node (heap numbering: root 1, children 2i and 2i + 1) */
    float *split;
    int k;
    int32_t *out;
} tree;

static float coordinate(const tree *t, int32_t i, int axis) { return t->points[3 * (int64_t)i + axis]; }

/* Put the element of rank `nth` of index[lo .. hi) by coordinate `axis` at nth, smaller ones
 * before, larger after (quickselect, three-way partition: duplicates cost nothing). */
static void select_nth(tree *t, int64_t lo, int64_t hi, int64_t nth, int axis) {
    int32_t *v = t->index;
    while (hi - lo > 1) {
        const float a = coordinate(t, v[lo], axis), b = coordinate(t, v[(lo + hi) / 2], axis),
                    c = coordinate(t, v[hi - 1], axis);
        const float pivot = a < b ? (b < c ? b : a < c ? c : a) : (a < c ? a : b < c ? c : b);
        int64_t lt = lo, i = lo, gt = hi; /* [lo, lt) < pivot, [lt, i) == pivot, [gt, hi) > */
        while (i < gt) {
            const float x = coordinate(t, v[i], axis);
            if (x < pivot) {
                const int32_t s = v[lt]; v[lt++] = v[i]; v[i++] = s;
            } else if (x > pivot) {
                const int32_t s = v[--gt]; v[gt] = v[i]; v[i] = s;
            } else {
                ++i;
            }
        }
        if (nth < lt) hi = lt;
        else if (nth >= gt) lo = gt;
        else return;
    }
}

static void build(tree *t, int64_t node, int64_t lo, int64_t hi) {
    if (hi - lo <= LEAF) return;
    float low[3], high[3];
    for (int a = 0; a < 3; ++a) low[a] = high[a] = coordinate(t, t->index[lo], a);
    for (int64_t i = lo + 1; i < hi; ++i)
        for (int a = 0; a < 3; ++a) {
            const float x = coordinate(t, t->index[i], a);
            low[a] = x < low[a] ? x : low[a], high[a] = x > high[a] ? x : high[a];
        }
    int axis = 0;
    for (int a = 1; a < 3; ++a)
        if (high[a] - low[a] > high[axis] - low[axis]) axis = a;
    const int64_t mid = lo + (hi - lo) / 2;
    select_nth(t, lo, hi, mid, axis);
    t->axis[node] = (uint8_t)axis;
    t->split[node] = coordinate(t, t->index[mid], axis);
    build(t, 2 * node, lo, mid);
    build(t, 2 * node + 1, mid, hi);
}

typedef struct {
    double d2[SC_MAX_NEIGHBOURS];
    int32_t index[SC_MAX_NEIGHBOURS];
    int count;
} best_list;

/* Insert (d2, index) into the sorted best list (at most k long). */
static void offer(best_list *b, int k, double d2, int32_t index) {
    int at = b->count;
    if (at == k) {
        if (d2 > b->d2[k - 1] || (d2 == b->d2[k - 1] && index > b->index[k - 1])) return;
        at = k - 1;
    } else {
        ++b->count;
    }
    while (at > 0 && (b->d2[at - 1] > d2 || (b->d2[at - 1] == d2 && b->index[at - 1] > index))) {
        b->d2[at] = b->d2[at - 1], b->index[at] = b->index[at - 1];
        --at;
    }
    b->d2[at] = d2, b->index[at] = index;
}

static void search(const tree *t, int64_t node, int64_t lo, int64_t hi, int32_t self,
                   const float *p, best_list *b) {
    if (hi - lo <= LEAF) {
        for (int64_t s = lo; s < hi; ++s) {
            const int32_t other = t->index[s];
            if (other == self) continue;
            const float *q = t->points + 3 * (int64_t)other;
            const double dx = (double)q[0] - p[0], dy = (double)q[1] - p[1], dz = (double)q[2] - p[2];
            offer(b, t->k, dx * dx + dy * dy + dz * dz, other);
        }
        return;
    }
    const int64_t mid = lo + (hi - lo) / 2;
    const double gap = (double)p[t->axis[node]] - t->split[node];
    /* the split value's point starts the upper half; equal coordinates may lie on both sides */
    const int lower_first = gap < 0.0;
    if (lower_first) search(t, 2 * node, lo, mid, self, p, b);
    else search(t, 2 * node + 1, mid, hi, self, p, b);
    if (b->count < t->k || gap * gap <= b->d2[t->k - 1]) {
        if (lower_first) search(t, 2 * node + 1, mid, hi, self, p, b);
        else search(t, 2 * node, lo, mid, self, p, b);
    }
}

typedef struct {
    const tree *t;
    int64_t n;
} job;

static void search_rows(void *ctx, int64_t begin, int64_t end, int thread) {
    (void)thread;
    const job *j = ctx;
    const tree *t = j->t;
    for (int64_t i = begin; i < end; ++i) {
        best_list b;
        b.count = 0;
        search(t, 1, 0, j->n, (int32_t)i, t->points + 3 * i, &b);
        int32_t *out = t->out + (int64_t)t->k * i;
        for (int m = 0; m < t->k; ++m) out[m] = m < b.count ? b.index[m] : -1;
    }
}

int sc_neighbours(const float *points, int64_t n, int k, int32_t *out, int threads) {
    if (k < 1 || k > SC_MAX_NEIGHBOURS) return -1;
    if (n == 0) return 0;
    int64_t nodes = 2;
    while (nodes < 4 * (n / LEAF + 1)) nodes *= 2; /* a heap deep enough for halving to LEAF */
    tree t = {.points = points, .k = k, .out = out};
    t.index = malloc(sizeof *t.index * (size_t)n);
    t.axis = calloc((size_t)nodes, sizeof *t.axis);
    t.split = calloc((size_t)nodes, sizeof *t.split);
    if (!t.index || !t.axis || !t.split) {
        free(t.index), free(t.axis), free(t.split);
        return -2;
    }
    for (int64_t i = 0; i < n; ++i) t.index[i] = (int32_t)i;
    build(&t, 1, 0, n);
    job j = {.t = &t, .n = n};
    sc_parallel_for(threads < 1 ? 1 : threads, n, GRAIN, search_rows, &j);
    free(t.index), free(t.axis), free(t.split);
    return 0;
}
