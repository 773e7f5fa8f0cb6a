/* hello.c: the C API in one file. Alpha's Plan sends Charlie's Act a Command, checks that it
 * was delivered, and Charlie polls for it the thesis's way (CheckForMessage,
 * GetNextMessageType, GetMessage); then a callback takes the next one.
 *
 *   hello [FLEET]     (default: hello.toml beside the source, as installed by CMake)
 *
 * Payloads are MessagePack, written by hand here: {"code": 1} is the Rust struct
 * `Command { code: u8 }` (#[message(id = 0)]) and the Python dataclass of the same field. */
#define _DEFAULT_SOURCE /* usleep */
#include <hetcomm.h>
#include <stdatomic.h>
#include <stdio.h>
#include <string.h>
#include <unistd.h>

enum { COMMAND = 0 };

static int fail(const char *what, hetcomm_status s) {
    fprintf(stderr, "%s: %s: %s\n", what, hetcomm_status_name(s), hetcomm_last_error());
    return 1;
}

static atomic_int callbacks_seen;

/* Runs on Charlie.Act's callback thread, a thread of the library. */
static void on_command(void *user, const hetcomm_envelope *env, const uint8_t *data, size_t len) {
    const char *label = user;
    printf("%s: command %u from %s.%s (%zu bytes)\n", label, data[len - 1], env->source_system_name,
           env->source_module_name, len);
    atomic_fetch_add(&callbacks_seen, 1);
}

int main(int argc, char **argv) {
    const char *fleet = argc > 1 ? argv[1] : HELLO_FLEET;
    hetcomm_comm *alpha = NULL, *charlie = NULL;
    hetcomm_module *plan = NULL, *act = NULL;
    hetcomm_status s;
    if ((s = hetcomm_comm_open(fleet, "Alpha", &alpha))) return fail("open Alpha", s);
    if ((s = hetcomm_comm_open(fleet, "Charlie", &charlie))) return fail("open Charlie", s);
    if ((s = hetcomm_comm_module(alpha, "Plan", &plan))) return fail("Alpha.Plan", s);
    if ((s = hetcomm_comm_module(charlie, "Act", &act))) return fail("Charlie.Act", s);

    const uint8_t turn_left[] = {0x81, 0xa4, 'c', 'o', 'd', 'e', 0x01}; /* {"code": 1} */
    hetcomm_ticket *ticket = NULL;
    s = hetcomm_module_send(plan, "Charlie", "Act", COMMAND, turn_left, sizeof turn_left,
                            HETCOMM_PRIORITY_NORMAL, &ticket);
    if (s) return fail("send", s);
    hetcomm_outcome outcome;
    if ((s = hetcomm_ticket_wait(ticket, &outcome))) return fail("wait", s);
    printf("send: %s after %u attempt(s)\n",
           outcome.kind == HETCOMM_OUTCOME_KIND_DELIVERED ? "delivered" : "not delivered",
           outcome.attempts);
    hetcomm_ticket_free(ticket);

    /* CheckForMessage, GetNextMessageType, GetMessage. */
    if (hetcomm_module_has_message(act)) {
        uint32_t type;
        if ((s = hetcomm_module_next_type(act, &type))) return fail("next_type", s);
        uint8_t buf[64];
        size_t len;
        hetcomm_envelope env;
        if ((s = hetcomm_module_recv(act, 0, buf, sizeof buf, &len, &env))) return fail("recv", s);
        printf("Charlie.Act: type %u, %zu bytes from %s.%s, code %u\n", type, len,
               env.source_system_name, env.source_module_name, buf[len - 1]);
    }

    /* From now on Commands go to a callback instead of the inbox. */
    if ((s = hetcomm_module_on(act, COMMAND, on_command, "Charlie.Act (callback)"))) return fail("on", s);
    const uint8_t stop[] = {0x81, 0xa4, 'c', 'o', 'd', 'e', 0x02};
    if ((s = hetcomm_module_send(plan, "Charlie", "Act", COMMAND, stop, sizeof stop, 200, NULL)))
        return fail("send", s);
    for (int i = 0; i < 500 && atomic_load(&callbacks_seen) == 0; i++) usleep(2000);

    hetcomm_stats stats;
    hetcomm_comm_stats(alpha, &stats);
    printf("Alpha: %llu sends, %llu delivered\n", (unsigned long long)stats.sends,
           (unsigned long long)stats.delivered);
    /* The system closes (and its callback thread stops) when its last handle is freed. */
    hetcomm_module_free(plan);
    hetcomm_module_free(act);
    hetcomm_comm_close(alpha);
    hetcomm_comm_close(charlie);
    return atomic_load(&callbacks_seen) == 1 ? 0 : 1;
}
