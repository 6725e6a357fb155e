/*
 * fmi2_host: a minimal FMI 2.0 co-simulation host in C, no Python involved.
 *
 * It proves that webline's element FMUs (pythonfmu 0.7) run in a non-Python
 * FMI tool. The FMU binary does not link libpython: the process must provide
 * it, e.g. LD_PRELOAD=.../libpython3.11.so, with PYTHONHOME pointing at that
 * Python's installation (see tests/test_c_host.py and the README).
 *
 * Usage:
 *   fmi2_host UNZIPDIR MODEL_ID GUID T0 H N [-s VR=VALUE]... [-o VR[:NAME]]...
 *
 *   UNZIPDIR  folder the .fmu was extracted into (holds modelDescription.xml)
 *   MODEL_ID  CoSimulation/@modelIdentifier: loads binaries/linux64/MODEL_ID.so
 *   GUID      fmiModelDescription/@guid
 *   T0, H, N  start time, communication step, number of steps
 *   -s VR=V   set Real VR to V in initialisation mode (parameters, inputs)
 *   -o VR:NAME  Real output to print (NAME for the CSV header, default vrVR)
 *
 * Prints CSV to stdout: "time,NAME..." then one row after initialisation and
 * one after every step, values as %.17g (exact doubles). FMU log messages go
 * to stderr as "[status] instance (category): message".
 *
 * Exit codes: 0 success, 1 usage, 2 load/instantiate failure, 3 a non-OK
 * status from an FMI call (the call and status are printed on stderr).
 * After fmi2Error/fmi2Fatal the instance is not called again (the FMI
 * standard allows only fmi2FreeInstance after error, nothing after fatal;
 * pythonfmu instances can crash when called after a fatal error).
 */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <limits.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* ---- the few FMI 2.0 declarations a co-simulation host needs ------------ */
typedef void *fmi2Component;
typedef void *fmi2ComponentEnvironment;
typedef unsigned int fmi2ValueReference;
typedef double fmi2Real;
typedef int fmi2Boolean;
typedef const char *fmi2String;
#define fmi2True 1
#define fmi2False 0

typedef enum { fmi2OK, fmi2Warning, fmi2Discard, fmi2Error, fmi2Fatal, fmi2Pending } fmi2Status;
typedef enum { fmi2ModelExchange, fmi2CoSimulation } fmi2Type;

typedef void (*fmi2CallbackLogger)(fmi2ComponentEnvironment, fmi2String, fmi2Status, fmi2String,
                                   fmi2String, ...);
typedef void *(*fmi2CallbackAllocateMemory)(size_t, size_t);
typedef void (*fmi2CallbackFreeMemory)(void *);
typedef void (*fmi2StepFinished)(fmi2ComponentEnvironment, fmi2Status);

typedef struct {
    const fmi2CallbackLogger logger;
    const fmi2CallbackAllocateMemory allocateMemory;
    const fmi2CallbackFreeMemory freeMemory;
    const fmi2StepFinished stepFinished;
    const fmi2ComponentEnvironment componentEnvironment;
} fmi2CallbackFunctions;

typedef fmi2Component (*fmi2InstantiateTYPE)(fmi2String, fmi2Type, fmi2String, fmi2String,
                                             const fmi2CallbackFunctions *, fmi2Boolean, fmi2Boolean);
typedef fmi2Status (*fmi2SetupExperimentTYPE)(fmi2Component, fmi2Boolean, fmi2Real, fmi2Real,
                                              fmi2Boolean, fmi2Real);
typedef fmi2Status (*fmi2ComponentCallTYPE)(fmi2Component); /* Enter/ExitInitializationMode, Terminate */
typedef fmi2Status (*fmi2SetRealTYPE)(fmi2Component, const fmi2ValueReference[], size_t, const fmi2Real[]);
typedef fmi2Status (*fmi2GetRealTYPE)(fmi2Component, const fmi2ValueReference[], size_t, fmi2Real[]);
typedef fmi2Status (*fmi2DoStepTYPE)(fmi2Component, fmi2Real, fmi2Real, fmi2Boolean);
typedef void (*fmi2FreeInstanceTYPE)(fmi2Component);

/* ---- logger --------------------------------------------------------------- */
static const char *status_name(fmi2Status s)
{
    static const char *names[] = {"OK", "Warning", "Discard", "Error", "Fatal", "Pending"};
    return (s >= fmi2OK && s <= fmi2Pending) ? names[s] : "?";
}

/* Whether a printf format would read an argument: any directive other than "%%". */
static int consumes_arguments(const char *fmt)
{
    for (const char *p = fmt; *p; p++) {
        if (*p != '%')
            continue;
        if (p[1] == '%') {
            p++;
            continue;
        }
        return 1;
    }
    return 0;
}

/*
 * FMI 2.0 defines `message` as a printf format followed by its arguments.
 * pythonfmu 0.7 passes Python text (tracebacks, repr of values) as the format
 * and never any argument, so expanding a '%' directive in it would read an
 * argument that was never passed (undefined behaviour, a crash for %s).
 * Therefore: a format that reads no argument is expanded with vsnprintf into a
 * bounded buffer (only "%%" changes); any other is printed verbatim. Nothing
 * is read from the va_list that the format could not be sure was passed, and
 * no message can overflow a buffer.
 */
static void logger(fmi2ComponentEnvironment env, fmi2String instance, fmi2Status status,
                   fmi2String category, fmi2String message, ...)
{
    (void)env;
    char buf[8192];
    const char *text = message ? message : "(null)";
    if (message && !consumes_arguments(message)) {
        va_list args;
        va_start(args, message);
        vsnprintf(buf, sizeof buf, message, args);
        va_end(args);
        text = buf;
    }
    fprintf(stderr, "[%s] %s (%s): %s\n", status_name(status), instance ? instance : "?",
            category ? category : "", text);
    fflush(stderr);
}

static const fmi2CallbackFunctions callbacks = {logger, calloc, free, NULL, NULL};

/* ---- helpers ---------------------------------------------------------------- */
static void *sym(void *lib, const char *name)
{
    void *f = dlsym(lib, name);
    if (!f) {
        fprintf(stderr, "fmi2_host: missing symbol %s: %s\n", name, dlerror());
        exit(2);
    }
    return f;
}

static void check(fmi2Status s, const char *call)
{
    if (s != fmi2OK) {
        fprintf(stderr, "fmi2_host: %s returned %d (fmi2%s)\n", call, (int)s, status_name(s));
        fflush(stdout);
        exit(3); /* the instance is not called again (see the header comment) */
    }
}

static double number(const char *s, const char *what)
{
    char *end;
    double v = strtod(s, &end);
    if (end == s || *end) {
        fprintf(stderr, "fmi2_host: bad %s '%s'\n", what, s);
        exit(1);
    }
    return v;
}

static fmi2ValueReference value_reference(const char *s, char **end)
{
    unsigned long v = strtoul(s, end, 10);
    if (*end == s || v > UINT_MAX) {
        fprintf(stderr, "fmi2_host: bad value reference in '%s'\n", s);
        exit(1);
    }
    return (fmi2ValueReference)v;
}

/* file:// URI of a local folder. pythonfmu 0.7 strips "file://" and decodes
   only "%20", so only spaces are escaped. */
static char *file_uri(const char *dir)
{
    size_t n = strlen("file://") + 3 * strlen(dir) + 1;
    char *uri = malloc(n), *q = uri;
    q += sprintf(q, "file://");
    for (const char *p = dir; *p; p++)
        q += (*p == ' ') ? sprintf(q, "%%20") : sprintf(q, "%c", *p);
    return uri;
}

int main(int argc, char **argv)
{
    if (argc < 7) {
        fprintf(stderr, "usage: %s UNZIPDIR MODEL_ID GUID T0 H N [-s VR=VALUE]... [-o VR[:NAME]]...\n",
                argv[0]);
        return 1;
    }
    const char *model = argv[2], *guid = argv[3];
    double t0 = number(argv[4], "T0"), h = number(argv[5], "H");
    long n = (long)number(argv[6], "N");

    char dir[PATH_MAX];
    if (!realpath(argv[1], dir)) {
        perror(argv[1]);
        return 2;
    }

    int nargs = argc - 7;
    fmi2ValueReference *set_vr = calloc(nargs + 1, sizeof *set_vr), *out_vr = calloc(nargs + 1, sizeof *out_vr);
    fmi2Real *set_val = calloc(nargs + 1, sizeof *set_val), *out_val = calloc(nargs + 1, sizeof *out_val);
    const char **out_name = calloc(nargs + 1, sizeof *out_name);
    size_t nset = 0, nout = 0;
    for (int i = 7; i < argc; i++) {
        char *end;
        if (!strcmp(argv[i], "-s") && i + 1 < argc) {
            const char *a = argv[++i];
            set_vr[nset] = value_reference(a, &end);
            if (*end != '=') {
                fprintf(stderr, "fmi2_host: -s expects VR=VALUE, got '%s'\n", a);
                return 1;
            }
            set_val[nset++] = number(end + 1, "value");
        } else if (!strcmp(argv[i], "-o") && i + 1 < argc) {
            const char *a = argv[++i];
            out_vr[nout] = value_reference(a, &end);
            if (*end == ':') {
                out_name[nout] = end + 1;
            } else if (*end == '\0') {
                out_name[nout] = NULL;
            } else {
                fprintf(stderr, "fmi2_host: -o expects VR[:NAME], got '%s'\n", a);
                return 1;
            }
            nout++;
        } else {
            fprintf(stderr, "fmi2_host: unexpected argument '%s'\n", argv[i]);
            return 1;
        }
    }

    char lib_path[PATH_MAX + 256];
    snprintf(lib_path, sizeof lib_path, "%s/binaries/linux64/%s.so", dir, model);
    void *lib = dlopen(lib_path, RTLD_NOW | RTLD_LOCAL);
    if (!lib) {
        /* Without libpython in the process: "undefined symbol: Py..." */
        fprintf(stderr, "fmi2_host: cannot load %s: %s\n", lib_path, dlerror());
        return 2;
    }
    fmi2InstantiateTYPE instantiate = (fmi2InstantiateTYPE)sym(lib, "fmi2Instantiate");
    fmi2SetupExperimentTYPE setup = (fmi2SetupExperimentTYPE)sym(lib, "fmi2SetupExperiment");
    fmi2ComponentCallTYPE enter_init = (fmi2ComponentCallTYPE)sym(lib, "fmi2EnterInitializationMode");
    fmi2ComponentCallTYPE exit_init = (fmi2ComponentCallTYPE)sym(lib, "fmi2ExitInitializationMode");
    fmi2SetRealTYPE set_real = (fmi2SetRealTYPE)sym(lib, "fmi2SetReal");
    fmi2DoStepTYPE do_step = (fmi2DoStepTYPE)sym(lib, "fmi2DoStep");
    fmi2GetRealTYPE get_real = (fmi2GetRealTYPE)sym(lib, "fmi2GetReal");
    fmi2ComponentCallTYPE terminate = (fmi2ComponentCallTYPE)sym(lib, "fmi2Terminate");
    fmi2FreeInstanceTYPE free_instance = (fmi2FreeInstanceTYPE)sym(lib, "fmi2FreeInstance");

    char resources[PATH_MAX + 16];
    snprintf(resources, sizeof resources, "%s/resources", dir);
    char *uri = file_uri(resources);
    fmi2Component c = instantiate("c_host", fmi2CoSimulation, guid, uri, &callbacks, fmi2False, fmi2True);
    if (!c) {
        fprintf(stderr, "fmi2_host: fmi2Instantiate failed (resources %s)\n", uri);
        return 2;
    }

    check(setup(c, fmi2False, 0.0, t0, fmi2False, 0.0), "fmi2SetupExperiment");
    check(enter_init(c), "fmi2EnterInitializationMode");
    if (nset)
        check(set_real(c, set_vr, nset, set_val), "fmi2SetReal");
    check(exit_init(c), "fmi2ExitInitializationMode");

    printf("time");
    for (size_t k = 0; k < nout; k++) {
        if (out_name[k])
            printf(",%s", out_name[k]);
        else
            printf(",vr%u", out_vr[k]);
    }
    printf("\n");

    double t = t0;
    for (long i = 0;; i++) {
        if (nout)
            check(get_real(c, out_vr, nout, out_val), "fmi2GetReal");
        printf("%.17g", t);
        for (size_t k = 0; k < nout; k++)
            printf(",%.17g", out_val[k]);
        printf("\n");
        if (i == n)
            break;
        check(do_step(c, t, h, fmi2True), "fmi2DoStep");
        t = t0 + (double)(i + 1) * h;
    }
    fflush(stdout);

    check(terminate(c), "fmi2Terminate");
    free_instance(c);
    /* The FMU library is not dlclose()d: pythonfmu keeps the embedded
       interpreter running until the process exits. */
    free(uri);
    free(set_vr);
    free(out_vr);
    free(set_val);
    free(out_val);
    free(out_name);
    return 0;
}
