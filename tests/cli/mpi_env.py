"""mpi_env.py — how the tests launch npgc over MPI ranks: mpirun on loopback, and under the sanitizers OpenMPI's own
leaks suppressed (tests/mpi/lsan.supp, as tests/mpi/mpi.sh does), the sanitizers' options passed to every rank."""
import os


def mpi_launch(ranks, env=None):
    """(the command's prefix, its environment) for `ranks` ranks; run from the repository root."""
    env = dict(os.environ if env is None else env)
    asan = env.get("ASAN_OPTIONS", "")
    env.update(OMPI_MCA_btl="self,vader", OMPI_MCA_btl_vader_single_copy_mechanism="none",
               OMPI_MCA_oob_tcp_if_include="lo", OMPI_MCA_rmaps_base_oversubscribe="1", OPENBLAS_NUM_THREADS="1",
               ASAN_OPTIONS=(asan + ":" if asan else "") + "fast_unwind_on_malloc=0",
               LSAN_OPTIONS="suppressions=%s/tests/mpi/lsan.supp" % os.getcwd(),
               OMPI_MCA_mca_base_component_disable_dlclose="1")
    return ["timeout", "300", "mpirun", "--allow-run-as-root", "--oversubscribe", "-x", "ASAN_OPTIONS", "-x",
            "LSAN_OPTIONS", "-np", str(ranks)], env
