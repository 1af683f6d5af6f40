"""Back-propagation associative memory with winner-take-all and a persistent long-term memory."""
