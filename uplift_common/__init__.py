"""What every package of the project shares and no package owns: the files the project writes and
reads back (``files``: atomic writes, output paths, checksums), the digest of the code a cached
value depends on (``code``), and the two error families every error class belongs to
(``errors``). It imports nothing of the project: the four packages may all import it."""
