/* Open / send / receive / close, again and again (ctest: leak_loop; run under valgrind by
 * scripts/cpp-test.sh, and with LeakSanitizer in the sanitizer build): every handle the C API
 * gives out is freed, and nothing the library allocates for them may be left behind.
 *
 *   leak_loop FLEET_TEMPLATE [ROUNDS] */
#define _DEFAULT_SOURCE
#include <hetcomm.h>

#include <arpa/inet.h>
#include <netinet/in.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <unistd.h>

#define OK(call)                                                                                 \
    do {                                                                                         \
        hetcomm_status s_ = (call);                                                              \
        if (s_ != HETCOMM_STATUS_OK) {                                                           \
            fprintf(stderr, "%s:%d: %s: %s: %s\n", __FILE__, __LINE__, #call,                    \
                    hetcomm_status_name(s_), hetcomm_last_error());                              \
            exit(1);                                                                             \
        }                                                                                        \
    } while (0)

static int free_udp_port(void) {
    int fd = socket(AF_INET, SOCK_DGRAM, 0);
    struct sockaddr_in a = {.sin_family = AF_INET, .sin_addr.s_addr = htonl(INADDR_LOOPBACK)};
    socklen_t len = sizeof a;
    if (fd < 0 || bind(fd, (struct sockaddr *)&a, sizeof a) || getsockname(fd, (struct sockaddr *)&a, &len)) exit(1);
    close(fd);
    return ntohs(a.sin_port);
}

static char *fleet_text(const char *template_text) {
    size_t cap = strlen(template_text) + 64;
    char *out = malloc(cap), *o = out;
    for (const char *p = template_text; *p;) {
        if (strncmp(p, "@KIND@", 6) == 0) { o += sprintf(o, "udp"); p += 6; }
        else if (strncmp(p, "@PORT_CPP@", 10) == 0) { o += sprintf(o, "%d", free_udp_port()); p += 10; }
        else if (strncmp(p, "@PORT_PEER@", 11) == 0) { o += sprintf(o, "%d", free_udp_port()); p += 11; }
        /* Both systems in this process, no key files: unsecured (the interop tests are secured). */
        else if (strncmp(p, "@SETTINGS@", 10) == 0) { o += sprintf(o, "security = \"none\""); p += 10; }
        else *o++ = *p++;
    }
    *o = 0;
    return out;
}

static pthread_mutex_t lock = PTHREAD_MUTEX_INITIALIZER;
static int callbacks;

static void on_msg(void *user, const hetcomm_envelope *env, const uint8_t *data, size_t len) {
    (void)user; (void)env; (void)data; (void)len;
    pthread_mutex_lock(&lock);
    callbacks++;
    pthread_mutex_unlock(&lock);
}

int main(int argc, char **argv) {
    if (argc < 2) { fprintf(stderr, "usage: leak_loop FLEET_TEMPLATE [ROUNDS]\n"); return 2; }
    int rounds = argc > 2 ? atoi(argv[2]) : 20;
    FILE *f = fopen(argv[1], "rb");
    if (!f) { perror(argv[1]); return 1; }
    char template_text[8192];
    size_t n = fread(template_text, 1, sizeof template_text - 1, f);
    template_text[n] = 0;
    fclose(f);

    for (int r = 0; r < rounds; r++) {
        char *fleet = fleet_text(template_text);
        hetcomm_comm *a, *b;
        hetcomm_module *ma, *mb;
        OK(hetcomm_comm_open_str(fleet, "leak.toml", "Cpp", &a));
        OK(hetcomm_comm_open_str(fleet, "leak.toml", "Peer", &b));
        free(fleet);
        OK(hetcomm_comm_module(a, "M", &ma));
        OK(hetcomm_comm_module(b, "M", &mb));
        OK(hetcomm_module_on(mb, 77, on_msg, NULL));
        uint8_t payload[300];
        memset(payload, r, sizeof payload);
        for (int i = 0; i < 3; i++) {
            hetcomm_ticket *t;
            hetcomm_outcome o;
            OK(hetcomm_module_send(ma, "Peer", "M", 1, payload, sizeof payload, 100, &t));
            OK(hetcomm_ticket_wait(t, &o));
            hetcomm_ticket_free(t);
            if (o.kind != HETCOMM_OUTCOME_KIND_DELIVERED) { fprintf(stderr, "not delivered\n"); return 1; }
        }
        OK(hetcomm_module_send(ma, "Peer", "M", 77, payload, 1, 100, NULL));
        hetcomm_broadcast *bc;
        OK(hetcomm_module_broadcast(ma, "M", 2, payload, 10, 100, &bc));
        hetcomm_outcome o;
        OK(hetcomm_ticket_wait(hetcomm_broadcast_ticket(bc, 0), &o));
        hetcomm_broadcast_free(bc);
        hetcomm_message *m;
        OK(hetcomm_module_recv_alloc(mb, 1000, &m));
        hetcomm_message_free(m);
        uint8_t small[4], buf[512];
        size_t len;
        if (hetcomm_module_recv(mb, 1000, small, sizeof small, &len, NULL) != HETCOMM_STATUS_BUFFER_TOO_SMALL) return 1;
        OK(hetcomm_module_recv(mb, 1000, buf, sizeof buf, &len, NULL));
        /* One message left in the inbox and one held back for a bigger buffer: both freed
         * with their handles. */
        if (hetcomm_module_recv(mb, 1000, small, sizeof small, &len, NULL) != HETCOMM_STATUS_BUFFER_TOO_SMALL) return 1;
        hetcomm_stats st;
        OK(hetcomm_comm_stats(a, &st));
        for (int i = 0; i < 2000; i++) { /* the callback runs on its own thread */
            pthread_mutex_lock(&lock);
            int seen = callbacks;
            pthread_mutex_unlock(&lock);
            if (seen > r) break;
            usleep(1000);
        }
        /* Errors leave a message for the thread; it is freed with the thread. */
        if (hetcomm_comm_module(a, "Nope", &ma) != HETCOMM_STATUS_UNKNOWN_MODULE) return 1;
        hetcomm_module_free(ma);
        hetcomm_module_free(mb);
        hetcomm_comm_close(a);
        hetcomm_comm_close(b);
    }
    printf("leak_loop: %d rounds, %d callbacks\n", rounds, callbacks);
    return callbacks == rounds ? 0 : 1;
}
