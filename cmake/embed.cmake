# embed.cmake — write INPUT as a C string constant NAME into OUTPUT, so a
# header is shared by the compiler and the code it generates without a
# second copy in the sources (STYLE: one ABI header).
file(READ ${INPUT} content HEX)
string(REGEX REPLACE "([0-9a-f][0-9a-f])" "0x\\1," content "${content}")
file(WRITE ${OUTPUT} "/* generated from ${INPUT} by cmake/embed.cmake */\nconst char ${NAME}[] = {${content} 0x00};\n")
