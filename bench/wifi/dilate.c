/* Time dilation for every process of one testbed run (LD_PRELOAD), after Gupta et al.,
 * "To Infinity and Beyond: Time-Warped Network Emulation", NSDI 2006: every clock the
 * run's processes read runs k times slower than real time, and every timeout they wait for
 * lasts k times longer, so ns-3 and the stacks live on one *experiment* clock that gives
 * each experiment second k real seconds of CPU. Read by docs/testbed.md ("Time dilation").
 *
 *   BENCH_DILATION="k anchor_realtime_ns anchor_monotonic_ns"
 *
 * Experiment time of clock c = anchor_c + (real_c - anchor_c) / k. The anchors come from the
 * harness, so all processes of a run agree on one experiment clock (and the harness, which
 * is not dilated, converts its own readings with the same formula).
 *
 * Why not Debian's libfaketime 0.9.10: each process anchors its clock at its own start
 * (processes started seconds apart disagree), and it does not wrap pthread_cond_clockwait
 * (GCC 12's std::condition_variable, used by ns-3 and Fast DDS), sem_clockwait (CPython
 * 3.11's lock timeouts) nor futex waits made through syscall(2) (Rust's std: zenoh). An
 * absolute deadline computed on the slowed clock and handed unconverted to the kernel
 * expires at once, so those waits turn into busy loops. Everything is wrapped here.
 *
 * Not dilated: the kernel's own timers (TCP retransmission, ARP, IGMP). The harness scales
 * the neighbour-cache timers per namespace; the rest is a stated limit of the method.
 */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <errno.h>
#include <linux/futex.h>
#include <poll.h>
#include <pthread.h>
#include <semaphore.h>
#include <signal.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <sys/epoll.h>
#include <sys/select.h>
#include <sys/syscall.h>
#include <sys/time.h>
#include <sys/timerfd.h>
#include <time.h>
#include <unistd.h>

#define NS 1000000000LL

static double g_k = 1.0;
static int g_on = 0;
static int64_t g_anchor_real = 0, g_anchor_mono = 0;

static int (*real_clock_gettime)(clockid_t, struct timespec*);

static int64_t ts_ns(const struct timespec* t) { return (int64_t)t->tv_sec * NS + t->tv_nsec; }

static struct timespec ns_ts(int64_t v)
{
    struct timespec t;
    if (v < 0) v = 0;
    t.tv_sec = v / NS;
    t.tv_nsec = v % NS;
    return t;
}

static void *next_sym(const char *name)
{
    void *p = dlsym(RTLD_NEXT, name);
    if (p == NULL) {
        fprintf(stderr, "dilate: no %s\n", name);
        abort();
    }
    return p;
}

__attribute__((constructor)) static void dilate_init(void)
{
    real_clock_gettime = next_sym("clock_gettime");
    const char *spec = getenv("BENCH_DILATION");
    if (spec == NULL) return;
    double k = 1.0;
    long long ar = 0, am = 0;
    if (sscanf(spec, "%lf %lld %lld", &k, &ar, &am) != 3 || !(k >= 1.0)) {
        fprintf(stderr, "dilate: bad BENCH_DILATION %s\n", spec);
        return;
    }
    g_k = k;
    g_anchor_real = ar;
    g_anchor_mono = am;
    g_on = k > 1.0;
}

/* The anchor of clock c, or -1 for clocks not dilated (CPU-time clocks). The monotonic
 * family shares the monotonic anchor shifted by its fixed offset to CLOCK_MONOTONIC. */
static int64_t anchor(clockid_t c)
{
    switch (c) {
    case CLOCK_REALTIME:
    case CLOCK_REALTIME_COARSE:
    case CLOCK_TAI:
        return g_anchor_real;
    case CLOCK_MONOTONIC:
    case CLOCK_MONOTONIC_RAW:
    case CLOCK_MONOTONIC_COARSE:
    case CLOCK_BOOTTIME: {
        if (c == CLOCK_MONOTONIC) return g_anchor_mono;
        struct timespec a, b;
        real_clock_gettime(CLOCK_MONOTONIC, &a);
        real_clock_gettime(c, &b);
        return g_anchor_mono + (ts_ns(&b) - ts_ns(&a));
    }
    default:
        return -1;
    }
}

static int64_t real_now(clockid_t c)
{
    struct timespec t;
    real_clock_gettime(c, &t);
    return ts_ns(&t);
}

static int64_t to_exp(clockid_t c, int64_t real)
{
    int64_t a = anchor(c);
    if (a < 0) return real;
    return a + (int64_t)((double)(real - a) / g_k);
}

static int64_t to_real(clockid_t c, int64_t exp)
{
    int64_t a = anchor(c);
    if (a < 0) return exp;
    return a + (int64_t)((double)(exp - a) * g_k);
}

static int64_t scale(int64_t d) { return (int64_t)((double)d * g_k); }

static struct timespec abs_to_real(clockid_t c, const struct timespec* t)
{
    return ns_ts(to_real(c, ts_ns(t)));
}

/* ---- clocks ---- */

int clock_gettime(clockid_t c, struct timespec* tp)
{
    int rc = real_clock_gettime(c, tp);
    if (rc == 0 && g_on) *tp = ns_ts(to_exp(c, ts_ns(tp)));
    return rc;
}

int __clock_gettime(clockid_t c, struct timespec* tp) { return clock_gettime(c, tp); }

int gettimeofday(struct timeval* tv, void* tz)
{
    static int (*f)(struct timeval*, void*);
    if (!f) f = next_sym("gettimeofday");
    int rc = f(tv, tz);
    if (rc == 0 && tv != NULL && g_on) {
        int64_t v = to_exp(CLOCK_REALTIME, (int64_t)tv->tv_sec * NS + tv->tv_usec * 1000LL);
        tv->tv_sec = v / NS;
        tv->tv_usec = (v % NS) / 1000;
    }
    return rc;
}

time_t time(time_t* out)
{
    struct timespec t;
    clock_gettime(CLOCK_REALTIME, &t);
    if (out) *out = t.tv_sec;
    return t.tv_sec;
}

int timespec_get(struct timespec* ts, int base)
{
    if (base != TIME_UTC) return 0;
    clock_gettime(CLOCK_REALTIME, ts);
    return base;
}

/* ---- sleeps ---- */

int nanosleep(const struct timespec* req, struct timespec* rem)
{
    static int (*f)(const struct timespec*, struct timespec*);
    if (!f) f = next_sym("nanosleep");
    if (!g_on || req == NULL) return f(req, rem);
    struct timespec r = ns_ts(scale(ts_ns(req)));
    int rc = f(&r, rem);
    if (rc != 0 && rem != NULL) *rem = ns_ts((int64_t)((double)ts_ns(rem) / g_k));
    return rc;
}

int clock_nanosleep(clockid_t c, int flags, const struct timespec* req, struct timespec* rem)
{
    static int (*f)(clockid_t, int, const struct timespec*, struct timespec*);
    if (!f) f = next_sym("clock_nanosleep");
    if (!g_on || req == NULL || anchor(c) < 0) return f(c, flags, req, rem);
    struct timespec r =
        (flags & TIMER_ABSTIME) ? abs_to_real(c, req) : ns_ts(scale(ts_ns(req)));
    int rc = f(c, flags, &r, rem);
    if (rc != 0 && rem != NULL && !(flags & TIMER_ABSTIME))
        *rem = ns_ts((int64_t)((double)ts_ns(rem) / g_k));
    return rc;
}

int usleep(useconds_t us)
{
    struct timespec r = ns_ts((int64_t)us * 1000LL);
    return nanosleep(&r, NULL);
}

unsigned int sleep(unsigned int s)
{
    struct timespec r = ns_ts((int64_t)s * NS), rem = {0, 0};
    if (nanosleep(&r, &rem) != 0) return (unsigned int)rem.tv_sec;
    return 0;
}

/* ---- waits on descriptors (timeouts relative) ---- */

static int scale_ms(int ms)
{
    if (!g_on || ms <= 0) return ms;
    double v = (double)ms * g_k;
    return v > 2147483647.0 ? 2147483647 : (int)v;
}

int poll(struct pollfd* fds, nfds_t n, int ms)
{
    static int (*f)(struct pollfd*, nfds_t, int);
    if (!f) f = next_sym("poll");
    return f(fds, n, scale_ms(ms));
}

int ppoll(struct pollfd* fds, nfds_t n, const struct timespec* t, const sigset_t* s)
{
    static int (*f)(struct pollfd*, nfds_t, const struct timespec*, const sigset_t*);
    if (!f) f = next_sym("ppoll");
    if (!g_on || t == NULL) return f(fds, n, t, s);
    struct timespec r = ns_ts(scale(ts_ns(t)));
    return f(fds, n, &r, s);
}

int select(int n, fd_set* r, fd_set* w, fd_set* e, struct timeval* t)
{
    static int (*f)(int, fd_set*, fd_set*, fd_set*, struct timeval*);
    if (!f) f = next_sym("select");
    if (!g_on || t == NULL) return f(n, r, w, e, t);
    int64_t v = scale((int64_t)t->tv_sec * NS + t->tv_usec * 1000LL);
    struct timeval tv = {v / NS, (v % NS) / 1000};
    int rc = f(n, r, w, e, &tv);
    int64_t left = (int64_t)((double)((int64_t)tv.tv_sec * NS + tv.tv_usec * 1000LL) / g_k);
    t->tv_sec = left / NS;
    t->tv_usec = (left % NS) / 1000;
    return rc;
}

int pselect(int n, fd_set* r, fd_set* w, fd_set* e, const struct timespec* t, const sigset_t* s)
{
    static int (*f)(int, fd_set*, fd_set*, fd_set*, const struct timespec*, const sigset_t*);
    if (!f) f = next_sym("pselect");
    if (!g_on || t == NULL) return f(n, r, w, e, t, s);
    struct timespec ts = ns_ts(scale(ts_ns(t)));
    return f(n, r, w, e, &ts, s);
}

int epoll_wait(int fd, struct epoll_event* ev, int max, int ms)
{
    static int (*f)(int, struct epoll_event*, int, int);
    if (!f) f = next_sym("epoll_wait");
    return f(fd, ev, max, scale_ms(ms));
}

int epoll_pwait(int fd, struct epoll_event* ev, int max, int ms, const sigset_t* s)
{
    static int (*f)(int, struct epoll_event*, int, int, const sigset_t*);
    if (!f) f = next_sym("epoll_pwait");
    return f(fd, ev, max, scale_ms(ms), s);
}

int epoll_pwait2(int fd, struct epoll_event* ev, int max, const struct timespec* t,
                 const sigset_t* s)
{
    static int (*f)(int, struct epoll_event*, int, const struct timespec*, const sigset_t*);
    if (!f) f = next_sym("epoll_pwait2");
    if (!g_on || t == NULL) return f(fd, ev, max, t, s);
    struct timespec r = ns_ts(scale(ts_ns(t)));
    return f(fd, ev, max, &r, s);
}

/* ---- waits with absolute deadlines ---- */

/* pthread_cond_timedwait's clock is the condition's (pthread_condattr_setclock), which
 * the wrapper cannot see: the deadline is matched to whichever dilated clock it is closer
 * to (realtime is ~1.7e9 s, monotonic is the uptime: never ambiguous on a live host). */
static clockid_t guess_clock(const struct timespec* t)
{
    struct timespec a, b;
    clock_gettime(CLOCK_REALTIME, &a);
    clock_gettime(CLOCK_MONOTONIC, &b);
    int64_t v = ts_ns(t);
    int64_t dr = v - ts_ns(&a), dm = v - ts_ns(&b);
    if (dr < 0) dr = -dr;
    if (dm < 0) dm = -dm;
    return dr < dm ? CLOCK_REALTIME : CLOCK_MONOTONIC;
}

int pthread_cond_timedwait(pthread_cond_t* c, pthread_mutex_t* m, const struct timespec* t)
{
    static int (*f)(pthread_cond_t*, pthread_mutex_t*, const struct timespec*);
    if (!f) f = dlvsym(RTLD_NEXT, "pthread_cond_timedwait", "GLIBC_2.3.2");
    if (!f) f = next_sym("pthread_cond_timedwait");
    if (!g_on || t == NULL) return f(c, m, t);
    struct timespec r = abs_to_real(guess_clock(t), t);
    return f(c, m, &r);
}

int pthread_cond_clockwait(pthread_cond_t* c, pthread_mutex_t* m, clockid_t clk,
                           const struct timespec* t)
{
    static int (*f)(pthread_cond_t*, pthread_mutex_t*, clockid_t, const struct timespec*);
    if (!f) f = next_sym("pthread_cond_clockwait");
    if (!g_on || t == NULL) return f(c, m, clk, t);
    struct timespec r = abs_to_real(clk, t);
    return f(c, m, clk, &r);
}

int sem_timedwait(sem_t* s, const struct timespec* t)
{
    static int (*f)(sem_t*, const struct timespec*);
    if (!f) f = next_sym("sem_timedwait");
    if (!g_on || t == NULL) return f(s, t);
    struct timespec r = abs_to_real(CLOCK_REALTIME, t);
    return f(s, &r);
}

int sem_clockwait(sem_t* s, clockid_t clk, const struct timespec* t)
{
    static int (*f)(sem_t*, clockid_t, const struct timespec*);
    if (!f) f = next_sym("sem_clockwait");
    if (!g_on || t == NULL) return f(s, clk, t);
    struct timespec r = abs_to_real(clk, t);
    return f(s, clk, &r);
}

int pthread_mutex_timedlock(pthread_mutex_t* m, const struct timespec* t)
{
    static int (*f)(pthread_mutex_t*, const struct timespec*);
    if (!f) f = next_sym("pthread_mutex_timedlock");
    if (!g_on || t == NULL) return f(m, t);
    struct timespec r = abs_to_real(CLOCK_REALTIME, t);
    return f(m, &r);
}

/* ---- timer descriptors (asio, tokio may use them) ---- */

#define MAX_TFD 65536
static clockid_t g_tfd_clock[MAX_TFD];

int timerfd_create(clockid_t c, int flags)
{
    static int (*f)(clockid_t, int);
    if (!f) f = next_sym("timerfd_create");
    int fd = f(c, flags);
    if (fd >= 0 && fd < MAX_TFD) g_tfd_clock[fd] = c;
    return fd;
}

int timerfd_settime(int fd, int flags, const struct itimerspec* n, struct itimerspec* o)
{
    static int (*f)(int, int, const struct itimerspec*, struct itimerspec*);
    if (!f) f = next_sym("timerfd_settime");
    if (!g_on || n == NULL) return f(fd, flags, n, o);
    struct itimerspec r = *n;
    clockid_t c = (fd >= 0 && fd < MAX_TFD) ? g_tfd_clock[fd] : CLOCK_MONOTONIC;
    if (ts_ns(&n->it_value) != 0) {
        r.it_value = (flags & TFD_TIMER_ABSTIME) ? abs_to_real(c, &n->it_value)
                                                 : ns_ts(scale(ts_ns(&n->it_value)));
        if (ts_ns(&r.it_value) == 0) r.it_value.tv_nsec = 1;  /* 0 would disarm */
    }
    r.it_interval = ns_ts(scale(ts_ns(&n->it_interval)));
    int rc = f(fd, flags, &r, o);
    if (rc == 0 && o != NULL) {
        o->it_value = ns_ts((int64_t)((double)ts_ns(&o->it_value) / g_k));
        o->it_interval = ns_ts((int64_t)((double)ts_ns(&o->it_interval) / g_k));
    }
    return rc;
}

int timerfd_gettime(int fd, struct itimerspec* cur)
{
    static int (*f)(int, struct itimerspec*);
    if (!f) f = next_sym("timerfd_gettime");
    int rc = f(fd, cur);
    if (rc == 0 && g_on && cur != NULL) {
        cur->it_value = ns_ts((int64_t)((double)ts_ns(&cur->it_value) / g_k));
        cur->it_interval = ns_ts((int64_t)((double)ts_ns(&cur->it_interval) / g_k));
    }
    return rc;
}

/* ---- futex through syscall(2): Rust's std parks and condvars (zenoh) ---- */

long syscall(long nr, ...)
{
    static long (*f)(long, ...);
    if (!f) f = next_sym("syscall");
    va_list ap;
    va_start(ap, nr);
    long a[6];
    for (int i = 0; i < 6; ++i) a[i] = va_arg(ap, long);
    va_end(ap);
    if (g_on && nr == SYS_clock_gettime) {
        int rc = (int)f(nr, a[0], a[1]);
        struct timespec* tp = (struct timespec*)a[1];
        if (rc == 0 && tp != NULL) *tp = ns_ts(to_exp((clockid_t)a[0], ts_ns(tp)));
        return rc;
    }
    if (g_on && nr == SYS_futex && a[3] != 0) {
        int op = (int)a[1];
        int cmd = op & FUTEX_CMD_MASK;
        const struct timespec* t = (const struct timespec*)a[3];
        struct timespec r;
        if (cmd == FUTEX_WAIT) {  /* relative timeout */
            r = ns_ts(scale(ts_ns(t)));
            a[3] = (long)&r;
        } else if (cmd == FUTEX_WAIT_BITSET) {  /* absolute */
            r = abs_to_real((op & FUTEX_CLOCK_REALTIME) ? CLOCK_REALTIME : CLOCK_MONOTONIC, t);
            a[3] = (long)&r;
        }
        return f(nr, a[0], a[1], a[2], a[3], a[4], a[5]);
    }
    return f(nr, a[0], a[1], a[2], a[3], a[4], a[5]);
}
