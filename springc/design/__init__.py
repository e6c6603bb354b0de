"""Design tools: compute building-block parameters and write readable `.spr` files."""
