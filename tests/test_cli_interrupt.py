"""Ctrl-C during a long native call (issue 20): one line, exit 130, printed
lines kept, no temporary file left, within a second or two."""
import os
import signal
import subprocess
import sys
import textwrap
import threading

from stablelego_jax.cli.interrupt import prompt_interrupt

ROOT = os.path.join(os.path.dirname(__file__), "..")

# an endless XLA loop: the main thread never returns to Python, so Python's own
# handler never runs; only the watcher can answer Ctrl-C
SCRIPT = textwrap.dedent("""
    import sys
    from stablelego_jax.blas import inline_cpu_dispatch
    inline_cpu_dispatch()
    import jax, jax.numpy as jnp
    from jax import lax
    from stablelego_jax.cli.interrupt import prompt_interrupt
    from stablelego_jax.files import staged_outputs

    x = jnp.zeros(1)
    spin = jax.jit(lambda v: lax.while_loop(lambda u: u[0] >= 0, lambda u: u + 1.0, v)).lower(x).compile()
    out = sys.argv[1]
    with prompt_interrupt("test: interrupted", code=130):
        with staged_outputs([out]) as stage:
            with open(stage(out), "w") as fh:
                fh.write("half")
            print("before the long call")  # buffered (stdout is a pipe): flushed on the way out
            sys.stderr.write("ready\\n")
            sys.stderr.flush()
            spin(x).block_until_ready()
    print("not reached")
""")


def _env():
    return dict(os.environ, PYTHONPATH=os.path.abspath(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))


def test_ctrl_c_inside_a_native_call_ends_the_process(tmp_path):
    out = tmp_path / "o" / "result.json"
    out.parent.mkdir()
    p = subprocess.Popen([sys.executable, "-c", SCRIPT, str(out)], env=_env(), stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True,
                         preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        assert p.stderr.readline() == "ready\n"
        threading.Event().wait(0.5)  # well inside the XLA loop
        p.send_signal(signal.SIGINT)
        stdout, stderr = p.communicate(timeout=60)
    finally:
        if p.poll() is None:
            p.kill()
            p.communicate()
    assert p.returncode == 130, stderr
    assert stderr.strip() == "test: interrupted"
    assert stdout == "before the long call\n"
    assert os.listdir(out.parent) == []  # neither the output nor its temporary file


def test_the_usual_path_still_raises_keyboard_interrupt():
    # Python's own handler, as in a terminal (a test run started in the
    # background inherits SIGINT ignored, where prompt_interrupt rightly does nothing)
    inherited = signal.signal(signal.SIGINT, signal.default_int_handler)
    raised = False
    try:
        try:
            with prompt_interrupt("x"):
                assert signal.getsignal(signal.SIGINT) is not signal.default_int_handler
                signal.raise_signal(signal.SIGINT)
                for _ in range(1000):  # Python code: the handler runs at once
                    pass
        except KeyboardInterrupt:
            raised = True
        assert raised
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
        assert signal.set_wakeup_fd(-1) == -1  # the wakeup socket is given back
    finally:
        signal.signal(signal.SIGINT, inherited)


def test_nothing_changes_where_sigint_is_ignored_or_off_the_main_thread():
    old = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        with prompt_interrupt("x"):
            assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN
    finally:
        signal.signal(signal.SIGINT, old)
    seen = []

    def worker():
        with prompt_interrupt("x"):
            seen.append(signal.getsignal(signal.SIGINT))

    t = threading.Thread(target=worker)
    t.start()
    t.join()
    assert seen == [old]


# a computation left running on another thread (as an interrupted solve
# leaves one): end_process neither waits for it nor loses what was printed
PENDING = textwrap.dedent("""
    import sys, threading, time
    import jax, jax.numpy as jnp
    from jax import lax
    from stablelego_jax.cli.interrupt import end_process
    from stablelego_jax.files import atomic_write

    x = jnp.zeros(1)
    spin = jax.jit(lambda v: lax.while_loop(lambda u: u[0] >= 0, lambda u: u + 1.0, v)).lower(x).compile()
    threading.Thread(target=lambda: spin(x).block_until_ready(), daemon=True).start()
    time.sleep(0.5)
    print("printed")

    def write(fh):
        fh.write("half")
        end_process(130, "test: ended")  # inside a writer: its temporary file goes too

    atomic_write(sys.argv[1], write)
""")


def test_end_process_does_not_wait_for_a_computation_in_flight(tmp_path):
    out = tmp_path / "o" / "result.txt"
    out.parent.mkdir()
    p = subprocess.run([sys.executable, "-c", PENDING, str(out)], env=_env(), capture_output=True, text=True,
                       timeout=120)
    assert p.returncode == 130, p.stderr
    assert p.stdout == "printed\n"
    assert p.stderr.strip().splitlines()[-1] == "test: ended"
    assert os.listdir(out.parent) == []


def test_a_finished_command_ends_quickly_with_its_status_and_all_its_output(tmp_path):
    """The program (``python -m stablelego_jax``) ends without tearing JAX
    down once a command is done (``runtime.quick_exit``): its exit status stays (0,
    or 1 when an input failed), and every line reaches a reader that takes
    its time."""
    from stablelego_jax.generate.procedural import stairs
    from stablelego_jax.formats.reader import write_layout

    good = tmp_path / "stairs.json"
    write_layout(stairs(5), str(good))
    bad = tmp_path / "empty.json"
    bad.write_text("{}")
    cmd = [sys.executable, "-m", "stablelego_jax", "analyze", "--json", "--solver", "exact"]
    env = dict(os.environ, PYTHONPATH=ROOT)
    p = subprocess.Popen(cmd + [str(good)] * 40, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env)
    lines = []
    for line in p.stdout:  # a slow reader: the pipe fills and the writer waits
        lines.append(line)
        if len(lines) == 1:
            threading.Event().wait(1.5)
    p.wait(timeout=120)
    assert p.returncode == 0, p.stderr.read()
    assert len(lines) == 40 and all(line.endswith(b"}\n") for line in lines)
    r = subprocess.run(cmd + [str(good), str(bad)], capture_output=True, text=True, env=env, timeout=120)
    out = r.stdout.splitlines()
    assert r.returncode == 1 and len(out) == 2 and "layout is empty" in out[1]  # --json: an error line
