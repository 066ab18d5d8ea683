"""A disk that really fills up, for the disk-full tests (docs/faults.md#disk-full).

:func:`small_disk` mounts a small tmpfs (root, or CAP_SYS_ADMIN, is needed: the test is skipped
with the reason otherwise) and :meth:`SmallDisk.fill` fills it until the kernel refuses a byte,
so the next write that needs space fails in the kernel with ENOSPC, part-way if it spans a page.
:class:`WriteLimit` is a disk full after a given number of bytes for one file: the real file
below, written in full up to the limit (the rest of a write is cut, as the kernel cuts a short
write), then ENOSPC.
"""

import errno
import io
import os
import subprocess

import pytest

NO_SPACE = os.strerror(errno.ENOSPC)
FILLER = 'filler'


class SmallDisk:
    """A mounted tmpfs at :attr:`path`."""

    def __init__(self, path):
        self.path = path

    def fill(self):
        """Grow a filler file until the kernel refuses even one byte; returns its size (bytes)."""
        chunk = 1 << 16
        fd = os.open(self.path / FILLER, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o600)
        try:
            while chunk:
                try:
                    os.write(fd, bytes(chunk))
                except OSError as error:
                    if error.errno != errno.ENOSPC:
                        raise
                    chunk //= 2  # down to 1 byte: the filler's last page is full too
            return os.fstat(fd).st_size
        finally:
            os.close(fd)

    def free(self):
        """Remove the filler."""
        (self.path / FILLER).unlink()


def small_disk(mount_point, size='4m'):
    """Mount a tmpfs of ``size`` at ``mount_point`` (created); yields a :class:`SmallDisk`, then
    unmounts it. Skips the test, naming why, when mounting is not permitted."""
    mount_point.mkdir()
    command = ['mount', '-t', 'tmpfs', '-o', f'size={size},mode=0700', 'gsp-test-disk']
    try:
        subprocess.run([*command, str(mount_point)], check=True, capture_output=True, text=True)
    except FileNotFoundError:
        pytest.skip('a real full disk needs a small tmpfs: there is no mount command')
    except subprocess.CalledProcessError as error:
        pytest.skip(
            'a real full disk needs a small tmpfs, and mounting one is not permitted here '
            f'({error.stderr.strip() or error.returncode}): run the tests as root'
        )
    try:
        yield SmallDisk(mount_point)
    finally:
        subprocess.run(['umount', '--lazy', str(mount_point)], check=False, capture_output=True)


class WriteLimit(io.RawIOBase):
    """The real file ``raw`` (unbuffered) on a disk that is full after ``limit['bytes']`` bytes
    of it, while ``limit['full']``: a write beyond is cut short at the limit, the next raises
    ENOSPC. Wrap it in ``io.BufferedWriter`` for a file object like ``open(path, 'wb')``."""

    def __init__(self, raw, limit):
        super().__init__()
        self._raw, self._limit, self.written = raw, limit, 0

    def writable(self):
        return True

    def write(self, data):
        data = memoryview(data)
        if self._limit['full']:
            room = self._limit['bytes'] - self.written
            if room <= 0:
                raise OSError(errno.ENOSPC, NO_SPACE)
            data = data[:room]
        count = self._raw.write(data)
        self.written += count
        return count

    def fileno(self):
        return self._raw.fileno()

    def tell(self):
        return self._raw.tell()

    def close(self):
        self._raw.close()
        super().close()
