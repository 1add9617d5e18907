"""Builds ``integrators._aba``: the articulated-body algorithm behind a C interface
(``integrators/_aba.cpp``, which includes ``_aba_model.hpp`` and the generated ABA of COBRA's
structure, ``_aba_cobra.c``: ``tools/generate_aba.py`` writes it; a build needs no CasADi).

Everything else is in ``pyproject.toml``. The extension compiles against the headers of the
``libpinocchio`` and ``cmeel-eigen`` packages (the build requirements) and links against
``libpinocchio_default``, whose explicit instantiation of ABA it calls; at run time that library
is the one ``pin`` loads (``import pinocchio`` comes first, ``integrators/native.py``), found
through the wheel's ``cmeel.prefix/lib`` beside the package as well.
"""
from importlib.metadata import distribution

from setuptools import Extension, setup

prefix = distribution("libpinocchio").locate_file("cmeel.prefix")
eigen = distribution("cmeel-eigen").locate_file("cmeel.prefix")

aba = Extension(
    "integrators._aba",
    sources=["integrators/_aba.cpp"],
    depends=["integrators/_aba_model.hpp", "integrators/_aba_cobra.c"],
    include_dirs=[str(prefix / "include"), str(eigen / "include" / "eigen3")],
    library_dirs=[str(prefix / "lib")],
    libraries=["pinocchio_default"],
    # the definitions Pinocchio's CMake targets give their users: ABA from the library, not re-instantiated
    define_macros=[("PINOCCHIO_ENABLE_TEMPLATE_INSTANTIATION", None), ("BOOST_MPL_LIMIT_LIST_SIZE", "30"),
                   ("BOOST_MPL_LIMIT_VECTOR_SIZE", "30"), ("BOOST_MPL_CFG_NO_PREPROCESSED_HEADERS", None),
                   ("BOOST_FUSION_INVOKE_MAX_ARITY", "12"), ("NDEBUG", None)],
    extra_compile_args=["-std=c++17", "-O3"],
    extra_link_args=["-Wl,-rpath,$ORIGIN/../cmeel.prefix/lib"],
    language="c++",
)

setup(ext_modules=[aba])
