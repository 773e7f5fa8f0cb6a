/* The C API's own tests (ctest: c_api): every error path returns its code with a message,
 * buffers too small report the size needed and keep the message, outcomes of every kind,
 * broadcast, library-owned messages, callbacks on the module's callback thread with the user
 * pointer, statistics. Real systems: in-process fleets from text, and UDP fleets from
 * fleet.toml.in (argv[1]) with both systems opened in this process.
 *
 *   test_c_api FLEET_TEMPLATE */
#define _GNU_SOURCE
#include <hetcomm.h>

#include <arpa/inet.h>
#include <netinet/in.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <unistd.h>

static int checks;

#define CHECK(cond)                                                                              \
    do {                                                                                         \
        checks++;                                                                                \
        if (!(cond)) {                                                                           \
            fprintf(stderr, "%s:%d: check failed: %s (last error: %s)\n", __FILE__, __LINE__,    \
                    #cond, hetcomm_last_error());                                                \
            exit(1);                                                                             \
        }                                                                                        \
    } while (0)

/* A call that must fail with `code`, leaving a message that contains `needle`. */
#define EXPECT_ERR(call, code, needle)                                                           \
    do {                                                                                         \
        hetcomm_status s_ = (call);                                                              \
        if (s_ != (code) || strstr(hetcomm_last_error(), (needle)) == NULL) {                    \
            fprintf(stderr, "%s:%d: %s returned %s (%s), expected %s with \"%s\"\n", __FILE__,   \
                    __LINE__, #call, hetcomm_status_name(s_), hetcomm_last_error(),              \
                    hetcomm_status_name(code), needle);                                          \
            exit(1);                                                                             \
        }                                                                                        \
        checks++;                                                                                \
    } while (0)

#define OK(call) CHECK((call) == HETCOMM_STATUS_OK)

static const char *INPROC =
    "name = \"c-api-inproc\"\n"
    "[systems]\nAlpha = 0\nCharlie = 1\nTango = 2\n"
    "[modules]\nPlan = 0\nAct = 1\n"
    "[transports.wired]\nkind = \"inproc\"\n"
    "[transports.quiet]\nkind = \"inproc\"\ndelivery = \"unacknowledged\"\n"
    "[table]\ncolumns = [\"Alpha\", \"Charlie\", \"Tango\"]\n"
    "Alpha = [\"X\", \"wired\", \"quiet\"]\n"
    "Charlie = [\"wired\", \"X\", \"X\"]\n"
    "Tango = [\"quiet\", \"X\", \"X\"]\n";

static char *template_text;

static int free_udp_port(void) {
    int fd = socket(AF_INET, SOCK_DGRAM, 0);
    struct sockaddr_in a = {.sin_family = AF_INET, .sin_addr.s_addr = htonl(INADDR_LOOPBACK)};
    socklen_t len = sizeof a;
    CHECK(fd >= 0 && bind(fd, (struct sockaddr *)&a, sizeof a) == 0);
    CHECK(getsockname(fd, (struct sockaddr *)&a, &len) == 0);
    close(fd);
    return ntohs(a.sin_port);
}

/* Replaces every `key` in `text` (which it frees) by `value`. */
static char *replace(char *text, const char *key, const char *value) {
    size_t n = 0, kl = strlen(key), vl = strlen(value);
    for (const char *p = text; (p = strstr(p, key)); p += kl) n++;
    char *out = malloc(strlen(text) + n * vl + 1), *o = out;
    const char *p = text, *q;
    while ((q = strstr(p, key))) {
        memcpy(o, p, (size_t)(q - p));
        o += q - p;
        memcpy(o, value, vl);
        o += vl;
        p = q + kl;
    }
    strcpy(o, p);
    free(text);
    return out;
}

/* The UDP fleet of fleet.toml.in with extra transport settings; caller frees. Unsecured: both
 * systems are opened in this process from a string, with no key files (the interop tests, across
 * processes, are secured with `hetcomm keygen`). */
static char *udp_fleet(int port_cpp, int port_peer, const char *settings) {
    char a[16], b[16];
    snprintf(a, sizeof a, "%d", port_cpp);
    snprintf(b, sizeof b, "%d", port_peer);
    char *unsecured = malloc(strlen(settings) + 32);
    sprintf(unsecured, "security = \"none\"\n%s", settings);
    char *t = strdup(template_text);
    t = replace(t, "@KIND@", "udp");
    t = replace(t, "@PORT_CPP@", a);
    t = replace(t, "@PORT_PEER@", b);
    t = replace(t, "@SETTINGS@", unsecured);
    free(unsecured);
    return t;
}

static void test_open_errors(void) {
    hetcomm_comm *c = NULL;
    EXPECT_ERR(hetcomm_comm_open(NULL, "Alpha", &c), HETCOMM_STATUS_INVALID_ARGUMENT, "`path` is NULL");
    EXPECT_ERR(hetcomm_comm_open_str(INPROC, "t", "Alpha", NULL), HETCOMM_STATUS_INVALID_ARGUMENT, "`out` is NULL");
    EXPECT_ERR(hetcomm_comm_open_str(INPROC, "t", "Al\xff", &c), HETCOMM_STATUS_INVALID_ARGUMENT, "not UTF-8");
    EXPECT_ERR(hetcomm_comm_open("/nonexistent/fleet.toml", "Alpha", &c), HETCOMM_STATUS_CONFIG,
               "/nonexistent/fleet.toml");
    EXPECT_ERR(hetcomm_comm_open_str("[systems]\nAlpha = \"zero\"\n", "bad.toml", "Alpha", &c),
               HETCOMM_STATUS_CONFIG, "bad.toml:2:");
    EXPECT_ERR(hetcomm_comm_open_str(INPROC, "t", "Zulu", &c), HETCOMM_STATUS_UNKNOWN_SYSTEM, "Zulu");
    const char *dds = "[systems]\nA = 0\nB = 1\n[modules]\nM = 0\n[transports.d]\nkind = \"dds\"\n"
                      "[table]\ncolumns = [\"A\", \"B\"]\nA = [\"X\", \"d\"]\nB = [\"d\", \"X\"]\n";
    EXPECT_ERR(hetcomm_comm_open_str(dds, "dds.toml", "A", &c), HETCOMM_STATUS_TRANSPORT_UNAVAILABLE, "dds");
    CHECK(c == NULL); /* outputs are written only on success */

    /* A UDP port that is taken. */
    int fd = socket(AF_INET, SOCK_DGRAM, 0);
    struct sockaddr_in a = {.sin_family = AF_INET, .sin_addr.s_addr = htonl(INADDR_LOOPBACK)};
    socklen_t len = sizeof a;
    CHECK(bind(fd, (struct sockaddr *)&a, sizeof a) == 0 && getsockname(fd, (struct sockaddr *)&a, &len) == 0);
    char *fleet = udp_fleet(ntohs(a.sin_port), free_udp_port(), "");
    EXPECT_ERR(hetcomm_comm_open_str(fleet, "taken.toml", "Cpp", &c), HETCOMM_STATUS_TRANSPORT, "Cpp");
    free(fleet);
    close(fd);

    OK(hetcomm_comm_open_str(INPROC, "t", "Alpha", &c));
    hetcomm_module *m = NULL;
    EXPECT_ERR(hetcomm_comm_module(c, "Nope", &m), HETCOMM_STATUS_UNKNOWN_MODULE, "Nope");
    EXPECT_ERR(hetcomm_comm_module(NULL, "Plan", &m), HETCOMM_STATUS_INVALID_ARGUMENT, "`comm` is NULL");
    CHECK(strcmp(hetcomm_comm_name(c), "Alpha") == 0 && hetcomm_comm_id(c) == 0);
    CHECK(hetcomm_comm_name(NULL) == NULL);
    const char *name, *addr;
    EXPECT_ERR(hetcomm_comm_endpoint(c, 99, &name, &addr), HETCOMM_STATUS_INVALID_ARGUMENT, "out of range");
    hetcomm_comm_close(c);
    hetcomm_comm_close(NULL); /* ignored */
    CHECK(strcmp(hetcomm_status_name(HETCOMM_STATUS_BUFFER_TOO_SMALL), "HETCOMM_STATUS_BUFFER_TOO_SMALL") == 0);
    CHECK(strcmp(hetcomm_status_name(999), "unknown") == 0);
    CHECK(strlen(hetcomm_version()) > 0);
}

typedef struct {
    hetcomm_comm *alpha, *charlie, *tango;
    hetcomm_module *plan, *act, *tango_act;
} Fleet;

static Fleet open_inproc(void) {
    Fleet f;
    OK(hetcomm_comm_open_str(INPROC, "inproc.toml", "Alpha", &f.alpha));
    OK(hetcomm_comm_open_str(INPROC, "inproc.toml", "Charlie", &f.charlie));
    OK(hetcomm_comm_open_str(INPROC, "inproc.toml", "Tango", &f.tango));
    OK(hetcomm_comm_module(f.alpha, "Plan", &f.plan));
    OK(hetcomm_comm_module(f.charlie, "Act", &f.act));
    OK(hetcomm_comm_module(f.tango, "Act", &f.tango_act));
    return f;
}

static void close_fleet(Fleet *f) {
    hetcomm_module_free(f->plan);
    hetcomm_module_free(f->act);
    hetcomm_module_free(f->tango_act);
    hetcomm_comm_close(f->alpha);
    hetcomm_comm_close(f->charlie);
    hetcomm_comm_close(f->tango);
}

static void test_send_and_receive(void) {
    Fleet f = open_inproc();
    const uint8_t hello[] = {0xa5, 'h', 'e', 'l', 'l', 'o'};
    hetcomm_ticket *t = NULL;
    hetcomm_outcome o;

    /* Errors mean nothing was sent. */
    EXPECT_ERR(hetcomm_module_send(f.plan, "Zulu", "Act", 3, hello, sizeof hello, 100, &t),
               HETCOMM_STATUS_UNKNOWN_SYSTEM, "Zulu");
    EXPECT_ERR(hetcomm_module_send(f.plan, "Charlie", "Nope", 3, hello, sizeof hello, 100, &t),
               HETCOMM_STATUS_UNKNOWN_MODULE, "Nope");
    EXPECT_ERR(hetcomm_module_send(f.plan, "Alpha", "Act", 3, hello, sizeof hello, 100, &t),
               HETCOMM_STATUS_NO_ROUTE, "X");
    EXPECT_ERR(hetcomm_module_send(f.plan, "Charlie", "Act", 3, NULL, 4, 100, &t),
               HETCOMM_STATUS_INVALID_ARGUMENT, "`data` is NULL");
    EXPECT_ERR(hetcomm_module_send(NULL, "Charlie", "Act", 3, hello, sizeof hello, 100, &t),
               HETCOMM_STATUS_INVALID_ARGUMENT, "`module` is NULL");
    size_t big = 17u << 20;
    uint8_t *huge = calloc(big, 1);
    EXPECT_ERR(hetcomm_module_send(f.plan, "Charlie", "Act", 3, huge, big, 100, &t), HETCOMM_STATUS_TOO_LARGE,
               "limit");
    free(huge);
    CHECK(t == NULL);
    CHECK(!hetcomm_module_has_message(f.act));
    uint32_t type = 0;
    EXPECT_ERR(hetcomm_module_next_type(f.act, &type), HETCOMM_STATUS_EMPTY, "no message");

    /* Delivered, then polled the thesis's way. */
    OK(hetcomm_module_send(f.plan, "Charlie", "Act", 3, hello, sizeof hello, 150, &t));
    OK(hetcomm_ticket_wait(t, &o));
    CHECK(o.kind == HETCOMM_OUTCOME_KIND_DELIVERED && o.attempts == 1 && o.reason == HETCOMM_FAIL_REASON_NONE);
    CHECK(strcmp(hetcomm_ticket_destination(t), "Charlie") == 0);
    OK(hetcomm_ticket_poll(t, &o));
    OK(hetcomm_ticket_wait_timeout(t, 10, &o));
    hetcomm_ticket_free(t);
    CHECK(hetcomm_module_has_message(f.act) && hetcomm_module_pending(f.act) == 1);
    OK(hetcomm_module_next_type(f.act, &type));
    CHECK(type == 3);

    /* Too small a buffer: the size needed, and the message stays. */
    uint8_t small[2];
    size_t len = 0;
    hetcomm_envelope env;
    EXPECT_ERR(hetcomm_module_recv(f.act, 0, small, sizeof small, &len, &env), HETCOMM_STATUS_BUFFER_TOO_SMALL,
               "6 bytes");
    CHECK(len == sizeof hello);
    len = 0;
    EXPECT_ERR(hetcomm_module_recv(f.act, 0, NULL, 0, &len, NULL), HETCOMM_STATUS_BUFFER_TOO_SMALL, "holds 0");
    CHECK(len == sizeof hello && hetcomm_module_has_message(f.act) && hetcomm_module_pending(f.act) == 1);
    OK(hetcomm_module_next_type(f.act, &type));
    CHECK(type == 3);
    EXPECT_ERR(hetcomm_module_recv(f.act, 0, NULL, 5, &len, NULL), HETCOMM_STATUS_INVALID_ARGUMENT, "`buf` is NULL");
    EXPECT_ERR(hetcomm_module_recv(f.act, 0, small, 2, NULL, NULL), HETCOMM_STATUS_INVALID_ARGUMENT, "`len` is NULL");
    uint8_t buf[64];
    OK(hetcomm_module_recv(f.act, 0, buf, sizeof buf, &len, &env));
    CHECK(len == sizeof hello && memcmp(buf, hello, len) == 0);
    CHECK(env.message_type == 3 && env.source_system == 0 && env.priority == 150 && !env.broadcast);
    CHECK(strcmp(env.source_system_name, "Alpha") == 0 && strcmp(env.source_module_name, "Plan") == 0);
    CHECK(env.timestamp_us > 0 && env.received_at_us > 0);
    EXPECT_ERR(hetcomm_module_recv(f.act, 0, buf, sizeof buf, &len, NULL), HETCOMM_STATUS_EMPTY, "no message");
    EXPECT_ERR(hetcomm_module_recv(f.act, 30, buf, sizeof buf, &len, NULL), HETCOMM_STATUS_TIMEOUT, "no message");

    /* Priority first, then arrival: a library-owned buffer of any size. */
    const uint8_t low[] = {0x01}, high[] = {0x02};
    OK(hetcomm_module_send(f.plan, "Charlie", "Act", 4, low, 1, 10, NULL));
    OK(hetcomm_module_send(f.plan, "Charlie", "Act", 5, high, 1, 250, NULL));
    hetcomm_message *msg = NULL;
    OK(hetcomm_module_recv_alloc(f.act, -1, &msg));
    size_t n = 0;
    const uint8_t *data = hetcomm_message_data(msg, &n);
    CHECK(n == 1 && data[0] == 0x02 && hetcomm_message_envelope(msg)->message_type == 5);
    hetcomm_message_free(msg);
    OK(hetcomm_module_recv_alloc(f.act, 100, &msg));
    CHECK(hetcomm_message_envelope(msg)->priority == 10);
    hetcomm_message_free(msg);
    EXPECT_ERR(hetcomm_module_recv_alloc(f.act, 0, &msg), HETCOMM_STATUS_EMPTY, "no message");
    /* A typed receive leaves a message of another type first in line. */
    OK(hetcomm_module_send(f.plan, "Charlie", "Act", 4, low, 1, 100, NULL));
    EXPECT_ERR(hetcomm_module_recv_alloc_type(f.act, 5, 1000, &msg), HETCOMM_STATUS_WRONG_TYPE, "type 4, not 5");
    OK(hetcomm_module_next_type(f.act, &type));
    CHECK(type == 4 && hetcomm_module_pending(f.act) == 1);
    OK(hetcomm_module_recv_alloc_type(f.act, 4, 0, &msg));
    hetcomm_message_free(msg);
    EXPECT_ERR(hetcomm_module_recv_alloc(f.act, 0, NULL), HETCOMM_STATUS_INVALID_ARGUMENT, "`message` is NULL");

    /* Unacknowledged transport: sent, without confirmation. */
    OK(hetcomm_module_send(f.plan, "Tango", "Act", 3, hello, sizeof hello, 100, &t));
    OK(hetcomm_ticket_wait(t, &o));
    CHECK(o.kind == HETCOMM_OUTCOME_KIND_SENT);
    hetcomm_ticket_free(t);
    OK(hetcomm_module_recv(f.tango_act, 1000, buf, sizeof buf, &len, NULL));

    /* Broadcast: one ticket per destination the table allows. */
    hetcomm_broadcast *b = NULL;
    OK(hetcomm_module_broadcast(f.plan, "Act", 9, hello, sizeof hello, 100, &b));
    CHECK(hetcomm_broadcast_count(b) == 2);
    int seen_charlie = 0, seen_tango = 0;
    for (size_t i = 0; i < 2; i++) {
        const hetcomm_ticket *bt = hetcomm_broadcast_ticket(b, i);
        OK(hetcomm_ticket_wait(bt, &o));
        const char *d = hetcomm_ticket_destination(bt);
        if (strcmp(d, "Charlie") == 0) seen_charlie = o.kind == HETCOMM_OUTCOME_KIND_DELIVERED;
        if (strcmp(d, "Tango") == 0) seen_tango = o.kind == HETCOMM_OUTCOME_KIND_SENT;
    }
    CHECK(seen_charlie && seen_tango && hetcomm_broadcast_ticket(b, 2) == NULL);
    hetcomm_broadcast_free(b);
    OK(hetcomm_module_recv(f.act, 1000, buf, sizeof buf, &len, &env));
    CHECK(env.broadcast && env.message_type == 9);
    EXPECT_ERR(hetcomm_module_broadcast(f.plan, "Nope", 9, hello, sizeof hello, 100, NULL),
               HETCOMM_STATUS_UNKNOWN_MODULE, "Nope");

    hetcomm_stats st;
    OK(hetcomm_comm_stats(f.alpha, &st));
    CHECK(st.sends == 7 && st.delivered == 5 && st.sent == 2 && st.failed == 0);
    EXPECT_ERR(hetcomm_comm_stats(f.alpha, NULL), HETCOMM_STATUS_INVALID_ARGUMENT, "`out` is NULL");
    hetcomm_inbox_stats is;
    OK(hetcomm_module_inbox_stats(f.act, &is));
    CHECK(is.accepted == 5 && is.taken == 5 && is.len == 0 && is.dropped == 0);
    close_fleet(&f);
}

typedef struct {
    pthread_mutex_t lock;
    pthread_t main_thread, first_thread;
    int count, any_count, same_thread, order_ok, last;
    int magic;
} Seen;

static void on_type_5(void *user, const hetcomm_envelope *env, const uint8_t *data, size_t len) {
    Seen *s = user;
    pthread_mutex_lock(&s->lock);
    pthread_t me = pthread_self();
    if (s->count == 0) s->first_thread = me;
    if (!pthread_equal(me, s->first_thread) || pthread_equal(me, s->main_thread)) s->same_thread = 0;
    char name[16] = "";
    pthread_getname_np(me, name, sizeof name);
    if (strcmp(name, "hetcomm-cb-Act") != 0) s->same_thread = 0; /* the documented thread */
    if (len != 1 || env->message_type != 5 || data[0] != s->last + 1 || s->magic != 0x5eed) s->order_ok = 0;
    s->last = len == 1 ? data[0] : -1;
    s->count++;
    pthread_mutex_unlock(&s->lock);
}

static void on_anything(void *user, const hetcomm_envelope *env, const uint8_t *data, size_t len) {
    Seen *s = user;
    (void)data;
    (void)len;
    pthread_mutex_lock(&s->lock);
    if (env->message_type == 6) s->any_count++;
    pthread_mutex_unlock(&s->lock);
}

static void test_callbacks(void) {
    Fleet f = open_inproc();
    Seen seen = {.lock = PTHREAD_MUTEX_INITIALIZER, .same_thread = 1, .order_ok = 1, .magic = 0x5eed};
    seen.main_thread = pthread_self();
    EXPECT_ERR(hetcomm_module_on(f.act, 5, NULL, &seen), HETCOMM_STATUS_INVALID_ARGUMENT, "`callback` is NULL");
    OK(hetcomm_module_on(f.act, 5, on_type_5, &seen));
    OK(hetcomm_module_on_any(f.act, on_anything, &seen));
    for (uint8_t i = 1; i <= 20; i++) OK(hetcomm_module_send(f.plan, "Charlie", "Act", 5, &i, 1, 100, NULL));
    const uint8_t other = 0;
    OK(hetcomm_module_send(f.plan, "Charlie", "Act", 6, &other, 1, 100, NULL));
    for (int i = 0; i < 2000; i++) {
        pthread_mutex_lock(&seen.lock);
        int done = seen.count == 20 && seen.any_count == 1;
        pthread_mutex_unlock(&seen.lock);
        if (done) break;
        usleep(1000);
    }
    pthread_mutex_lock(&seen.lock);
    CHECK(seen.count == 20 && seen.any_count == 1);
    CHECK(seen.same_thread); /* one callback thread per module, never the caller's */
    CHECK(seen.order_ok);    /* arrival order, the user pointer intact */
    pthread_mutex_unlock(&seen.lock);
    CHECK(!hetcomm_module_has_message(f.act)); /* callbacks take messages instead of the inbox */
    close_fleet(&f); /* returns after the callback thread stopped: `seen` may go now */
}

static void on_inline(void *user, const hetcomm_envelope *env, const uint8_t *data, size_t len) {
    Seen *s = user;
    (void)env;
    (void)data;
    (void)len;
    pthread_mutex_lock(&s->lock);
    if (!pthread_equal(pthread_self(), s->main_thread)) s->same_thread = 0;
    s->count++;
    pthread_mutex_unlock(&s->lock);
}

static void test_inline_callbacks(void) {
    /* In process, an inline callback runs on the sender's thread, before the send returns. */
    Fleet f = open_inproc();
    Seen seen = {.lock = PTHREAD_MUTEX_INITIALIZER, .same_thread = 1};
    seen.main_thread = pthread_self();
    EXPECT_ERR(hetcomm_module_set_inline_callbacks(NULL, true), HETCOMM_STATUS_INVALID_ARGUMENT, "`module` is NULL");
    OK(hetcomm_module_set_inline_callbacks(f.act, true));
    OK(hetcomm_module_on(f.act, 5, on_inline, &seen));
    for (uint8_t i = 1; i <= 5; i++) OK(hetcomm_module_send(f.plan, "Charlie", "Act", 5, &i, 1, 100, NULL));
    pthread_mutex_lock(&seen.lock);
    CHECK(seen.count == 5);   /* already run: no callback thread in between */
    CHECK(seen.same_thread);  /* on the caller's thread */
    pthread_mutex_unlock(&seen.lock);
    close_fleet(&f);
}

static void test_udp_outcomes(void) {
    /* Both systems of the UDP fleet in this process: acknowledged, delivered. */
    char *fleet = udp_fleet(free_udp_port(), free_udp_port(), "");
    hetcomm_comm *cpp, *peer;
    hetcomm_module *a, *b;
    OK(hetcomm_comm_open_str(fleet, "udp.toml", "Cpp", &cpp));
    OK(hetcomm_comm_open_str(fleet, "udp.toml", "Peer", &peer));
    free(fleet);
    CHECK(hetcomm_comm_endpoint_count(cpp) == 1);
    const char *name, *addr;
    OK(hetcomm_comm_endpoint(cpp, 0, &name, &addr));
    CHECK(strcmp(name, "net") == 0 && strncmp(addr, "udp://127.0.0.1:", 16) == 0);
    OK(hetcomm_comm_module(cpp, "M", &a));
    OK(hetcomm_comm_module(peer, "M", &b));
    const uint8_t x[] = {0x2a};
    hetcomm_ticket *t;
    hetcomm_outcome o;
    OK(hetcomm_module_send(a, "Peer", "M", 1, x, 1, 100, &t));
    OK(hetcomm_ticket_wait(t, &o));
    CHECK(o.kind == HETCOMM_OUTCOME_KIND_DELIVERED && o.latency_us > 0);
    hetcomm_ticket_free(t);
    uint8_t buf[8];
    size_t len;
    OK(hetcomm_module_recv(b, 1000, buf, sizeof buf, &len, NULL));
    CHECK(len == 1 && buf[0] == 0x2a);
    hetcomm_module_free(a);
    hetcomm_module_free(b);
    hetcomm_comm_close(cpp);
    hetcomm_comm_close(peer);

    /* A peer that is not there: the window fills (backpressure), the send ends unconfirmed. */
    fleet = udp_fleet(free_udp_port(), free_udp_port(), "attempts = 2\nmax_in_flight = 1");
    OK(hetcomm_comm_open_str(fleet, "absent.toml", "Cpp", &cpp));
    free(fleet);
    OK(hetcomm_comm_module(cpp, "M", &a));
    OK(hetcomm_module_send(a, "Peer", "M", 1, x, 1, 100, &t));
    EXPECT_ERR(hetcomm_ticket_poll(t, &o), HETCOMM_STATUS_PENDING, "not ended");
    EXPECT_ERR(hetcomm_ticket_wait_timeout(t, 5, &o), HETCOMM_STATUS_TIMEOUT, "not ended");
    EXPECT_ERR(hetcomm_module_send(a, "Peer", "M", 1, x, 1, 100, NULL), HETCOMM_STATUS_BACKPRESSURE,
               "max_in_flight");
    OK(hetcomm_ticket_wait(t, &o));
    CHECK(o.kind == HETCOMM_OUTCOME_KIND_UNCONFIRMED && o.reason == HETCOMM_FAIL_REASON_NO_ACKNOWLEDGEMENT);
    CHECK(o.attempts == 2);
    hetcomm_ticket_free(t);
    hetcomm_stats st;
    OK(hetcomm_comm_stats(cpp, &st));
    CHECK(st.unconfirmed == 1 && st.backpressured == 1 && st.retransmissions == 1);
    hetcomm_module_free(a);
    hetcomm_comm_close(cpp);
}

static void test_path_switches(void) {
    /* A pair with two transports: moved while running, each move seen by two watches;
       refusals change nothing and say why. */
    static const char *fleet =
        "[systems]\nAlpha = 0\nCharlie = 1\n[modules]\nPlan = 0\n"
        "[transports.wired]\nkind = \"inproc\"\n[transports.spare]\nkind = \"inproc\"\n"
        "[table]\ncolumns = [\"Alpha\", \"Charlie\"]\n"
        "Alpha = [\"X\", \"wired,spare\"]\nCharlie = [\"wired,spare\", \"X\"]\n";
    hetcomm_comm *alpha, *charlie;
    OK(hetcomm_comm_open_str(fleet, "paths.toml", "Alpha", &alpha));
    OK(hetcomm_comm_open_str(fleet, "paths.toml", "Charlie", &charlie));
    hetcomm_path_watch *w1, *w2;
    OK(hetcomm_comm_watch_paths(alpha, &w1));
    OK(hetcomm_comm_watch_paths(alpha, &w2));
    hetcomm_path_switch s;
    EXPECT_ERR(hetcomm_path_watch_poll(w1, 0, &s), HETCOMM_STATUS_EMPTY, "no path switch");
    const char *spare[] = {"spare"};
    const char *both[] = {"wired", "spare"};
    OK(hetcomm_comm_set_transports(alpha, "Charlie", spare, 1));
    OK(hetcomm_path_watch_poll(w1, 1000, &s));
    CHECK(strcmp(s.to, "Charlie") == 0 && strcmp(s.from, "wired") == 0 && strcmp(s.now, "spare") == 0);
    CHECK(s.number == 1);
    OK(hetcomm_comm_set_transports(alpha, "Charlie", both, 2));
    OK(hetcomm_path_watch_poll(w1, 1000, &s));
    CHECK(strcmp(s.from, "spare") == 0 && strcmp(s.now, "wired") == 0 && s.number == 2);
    OK(hetcomm_path_watch_poll(w2, 0, &s));
    CHECK(s.number == 1);
    OK(hetcomm_path_watch_poll(w2, 0, &s));
    CHECK(s.number == 2);
    const char *bad[] = {"radio"};
    EXPECT_ERR(hetcomm_comm_set_transports(alpha, "Charlie", bad, 1), HETCOMM_STATUS_INVALID_ARGUMENT,
               "lists `wired,spare`");
    EXPECT_ERR(hetcomm_comm_set_transports(alpha, "Zulu", both, 2), HETCOMM_STATUS_UNKNOWN_SYSTEM, "Zulu");
    EXPECT_ERR(hetcomm_comm_set_transports(alpha, "Charlie", NULL, 0), HETCOMM_STATUS_INVALID_ARGUMENT,
               "at least one");
    EXPECT_ERR(hetcomm_path_watch_poll(w1, 10, &s), HETCOMM_STATUS_EMPTY, "no path switch");
    hetcomm_path_watch_free(w1);
    hetcomm_path_watch_free(w2);
    hetcomm_comm_close(alpha);
    hetcomm_comm_close(charlie);
}

static char *read_file(const char *path) {
    FILE *f = fopen(path, "rb");
    CHECK(f != NULL);
    fseek(f, 0, SEEK_END);
    long n = ftell(f);
    fseek(f, 0, SEEK_SET);
    char *text = malloc((size_t)n + 1);
    CHECK(fread(text, 1, (size_t)n, f) == (size_t)n);
    text[n] = 0;
    fclose(f);
    return text;
}

int main(int argc, char **argv) {
    if (argc != 2) {
        fprintf(stderr, "usage: test_c_api FLEET_TEMPLATE\n");
        return 2;
    }
    template_text = read_file(argv[1]);
    test_open_errors();
    test_send_and_receive();
    test_callbacks();
    test_inline_callbacks();
    test_udp_outcomes();
    test_path_switches();
    free(template_text);
    printf("test_c_api: %d checks passed\n", checks);
    return 0;
}
