# Copyright 2026 nh_tracking maintainers
#
# Licensed under the Apache License, Version 2.0 (the "License");
# you may not use this file except in compliance with the License.
# You may obtain a copy of the License at
#
#     http://www.apache.org/licenses/LICENSE-2.0
#
# Unless required by applicable law or agreed to in writing, software
# distributed under the License is distributed on an "AS IS" BASIS,
# WITHOUT WARRANTIES OR CONDITIONS OF ANY KIND, either express or implied.
# See the License for the specific language governing permissions and
# limitations under the License.

"""Compiled NLPs: C code generated from the CasADi NLP, built once with gcc, cached on disk.

Evaluating the NLP's derivatives in CasADi's virtual machine costs about two thirds of a cold
solve; compiled, the same solve takes about a third of the time. Compiling is slow (seconds
to tens of seconds, growing with N), so a library is keyed by the hash of its generated code
and kept in ``$NH_TRACKING_CACHE`` (default ``~/.cache/nh_tracking``): built once per
structure per machine, then loaded in milliseconds.
"""
from __future__ import annotations

import hashlib
import logging
import os
from pathlib import Path
import shutil
import subprocess
import tempfile

import casadi as ca

LOG = logging.getLogger(__name__)
FLAGS = ('-O1', '-fPIC', '-shared')


def cache_dir() -> Path:
    return Path(os.environ.get('NH_TRACKING_CACHE', Path.home() / '.cache' / 'nh_tracking'))


def compiled_library(solver: ca.Function) -> Path | None:
    """Path of a shared library holding ``solver``'s NLP functions.

    None if it cannot be built here (no C compiler), in which case the caller keeps the interpreted
    NLP.
    """
    compiler = shutil.which(os.environ.get('CC', 'gcc'))
    if compiler is None:
        LOG.warning('no C compiler found: using the interpreted NLP')
        return None
    with tempfile.TemporaryDirectory() as tmp:
        source = Path(_generate(solver, tmp))
        code = source.read_bytes()
        digest = hashlib.sha256(code + ' '.join(FLAGS).encode()).hexdigest()[:24]
        library = cache_dir() / f'nlp-{digest}.so'
        if library.exists():
            return library
        library.parent.mkdir(parents=True, exist_ok=True)
        partial = library.with_suffix(f'.{os.getpid()}.tmp')
        LOG.info('compiling the NLP (%d kB of C) into %s', len(code) // 1024, library)
        done = subprocess.run([compiler, *FLAGS, str(source), '-o', str(partial)],
                              capture_output=True, text=True)
        if done.returncode != 0:
            LOG.warning('compiling the NLP failed, using the interpreted one: %s',
                        done.stderr[-500:])
            partial.unlink(missing_ok=True)
            return None
        partial.replace(library)  # atomic: concurrent builders never load a partial file
        return library


def _generate(solver: ca.Function, directory: str) -> str:
    """C source of the NLP's functions in ``directory``: what ``generate_dependencies`` writes.

    Without changing the process's working directory (it only writes to the current one).
    """
    generator = ca.CodeGenerator('nlp.c')
    generator.add(solver.oracle())
    for name in solver.get_function():
        generator.add(solver.get_function(name))
    return generator.generate(directory + os.sep)
