import pytest

from stablelego_jax.blas import one_blas_thread, openblas_library


def test_one_blas_thread_sets_and_restores():
    lib = openblas_library()
    if lib is None:
        pytest.skip("SciPy without its bundled OpenBLAS")
    lib.scipy_openblas_set_num_threads(2)
    before = lib.scipy_openblas_get_num_threads()
    with one_blas_thread():
        assert lib.scipy_openblas_get_num_threads() == 1
    assert lib.scipy_openblas_get_num_threads() == before


def test_restored_after_an_error():
    lib = openblas_library()
    if lib is None:
        pytest.skip("SciPy without its bundled OpenBLAS")
    before = lib.scipy_openblas_get_num_threads()
    with pytest.raises(RuntimeError):
        with one_blas_thread():
            raise RuntimeError("inside")
    assert lib.scipy_openblas_get_num_threads() == before
