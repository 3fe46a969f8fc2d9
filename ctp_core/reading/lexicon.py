"""Typical real sizes of common objects, and how object names map onto them.

The rule-based prior needs a size for each named object (the size ratio is their quotient) and a few
coarse shape facts that decide contact and penetration (is it a container, is it pointed, flat, round,
soft, does it wrap around what wears it, is it someone who can hold or wear things). A language model
knows these; without one, this table is the knowledge.

Sizes are the *longest side* of the object's bounding box in metres, for a typical real instance (a
guess good to a factor of about two). Table rows: ``name[/alias...] size [tag,tag...]`` with ``_`` for
spaces; plurals are handled by ``singular`` so rows list singular forms only.

Tags:
- ``container``: has a cavity or opening things go into without cutting (cup, box, bun, keyhole).
- ``pointed``: thin or sharp enough to be pushed into a solid (knife, arrow, nail, candle, flag).
- ``staked``: pointed and made to stand stuck in what it is put on (candle, flag, toothpick): "on" a
  pierceable solid (a cake, a sandcastle) it goes into it, where a knife or a fork would lie on top.
- ``flat``: a sheet or slice that lies on one face (pepperoni, poster, sticker).
- ``round``: ball-like; touches a support at a point.
- ``soft``: drapes or settles onto a support (cushion, cat, towel).
- ``wrap``: a garment or band that hugs what wears it (scarf, glove, collar).
- ``agent``: a person, character or animal that can hold, wear, ride.
- ``aquatic``: a creature that lives under water (a fish, a jellyfish): in a liquid it is wholly under.
- ``pierceable``: a solid a pointed thing goes into when pushed (wood, soil, foam, a dartboard, fabric); solid
  food, plants and ``soft`` things are pierceable without the tag.
- ``bites``: a creature whose bite or sting pierces the skin (a mosquito, a tick, a wasp): biting or stinging
  someone, it goes into them.
- ``filled``: holds contents that close its opening off (a drink, a soup, a pond): what goes *in* it passes
  below the surface of the contents, so it penetrates (the prompt can say so too: "a mug of cocoa").

Each row belongs to the section it is listed under (``Entry.domain``): the domain decides between the senses of
a word listed in more than one row (``~mouse`` in a later row: the computer mouse is another sense of "mouse";
``SENSES``), by the other object of the prompt.

Names like ``rooster_comb`` or ``teapot_lid`` are parts: ``PARTS`` gives a part's size as a fraction
of its owner's, so any owner in the table works without listing every pair.
"""

from __future__ import annotations

import re
import unicodedata
from collections.abc import Iterable
from dataclasses import dataclass

_TABLE = """
# --- food and drink ---
apple 0.08 round
orange 0.08 round
lemon/lime 0.07 round
peach/plum/pear 0.08 round
cherry/grape/olive/blueberry/strawberry/raspberry 0.025 round
banana 0.2
watermelon 0.35 round
melon/pumpkin/pineapple 0.3
coconut 0.15 round
avocado/mango 0.1
tomato/onion/potato 0.08 round
carrot/cucumber/zucchini/eggplant/celery/parsnip/leek 0.2 pointed
corn/corn_cob/corn_on_the_cob/cob 0.2
mushroom 0.06
egg 0.06 round
bread/loaf 0.25
bread_roll/roll/bun 0.12 container
baguette 0.6 pointed
toast 0.11 flat
sandwich/burger/hamburger/cheeseburger 0.12
hotdog/hot_dog/sausage/frankfurter 0.15
patty 0.1 flat
pizza 0.35 flat
pepperoni 0.04 flat
cheese 0.1
roast_turkey/roast_chicken/roast 0.4
# cheeses as a block or a wheel (a wedge is a piece)
parmesan/cheddar/brie/camembert/gouda/edam/stilton/manchego/gruyere/emmental/cheese_block 0.15
cheese_wheel/wheel_of_cheese 0.4
cheese_slice/ham/bacon/lettuce/salmon_fillet/salmon 0.12 flat
steak/meat/chicken/fish_fillet 0.2
shrimp/prawn/calamari/squid_ring/tofu/halloumi/paneer 0.06
tortilla_chip/nacho/crisp/potato_chip 0.06 flat
chocolate_chip/raisin/sprinkle/currant 0.01
drumstick 0.15
clove/peppercorn/seed/bean/almond/peanut/walnut/hazelnut/pistachio/chickpea 0.02
garlic/chili/chilli 0.06
cinnamon/vanilla_pod/vanilla_bean/lemongrass/licorice/liquorice 0.1
rice/rice_ball/onigiri 0.07
sushi/nigiri/maki 0.06
cake 0.25
cupcake/muffin 0.07
cookie/biscuit/cracker/pancake/waffle 0.08 flat
biscotti/breadstick/churro/pretzel_stick 0.15
donut/doughnut/bagel 0.1
croissant 0.15
pie/tart/quiche 0.25
sundae/ice_cream_sundae/dessert 0.2
ice_cream/gelato 0.12
scoop/ice_cream_scoop 0.07 round
ice_cream_cone/waffle_cone/cone 0.15 container
popsicle/lollipop 0.15
candy/sweet/chocolate/praline 0.03
candy_cane 0.15
chocolate_bar 0.15 flat
marshmallow 0.04 soft
taco/burrito/wrap 0.18 container
noodle/pasta/spaghetti 0.2
soup/stew/broth/porridge/oatmeal/curry/ramen/chowder 0.2 container,filled
butter 0.1
honey/honey_jar/honey_pot/jam 0.12 container,filled
coffee/tea/latte/espresso/cappuccino/cocoa/hot_chocolate/iced_tea 0.09 container,filled
wine/beer/juice/milk/water/soda/drink/cocktail/martini/margarita 0.18 container,filled
lemonade/cola/whiskey/whisky/punch/champagne/prosecco/vodka/gin/rum/cider/sake 0.18 container,filled
mojito/daiquiri/pina_colada/sangria/mimosa/negroni/cosmopolitan/gin_and_tonic 0.18 container,filled
milkshake/smoothie/frappe 0.2 container,filled
macchiato/latte_macchiato/americano/mocha/flat_white/chai/matcha/frappuccino/kombucha/lassi/eggnog 0.15 container,filled
lager/ale/stout/spritz/shandy/julep/fizz/toddy/hot_toddy/whiskey_sour 0.18 container,filled
# cocktails and mixed drinks, served in their glass
bloody_mary/bloody_caesar/manhattan/old_fashioned/mai_tai/paloma/bellini/tequila_sunrise 0.18 container,filled
white_russian/long_island_iced_tea/mulled_wine/irish_coffee/pimms/aperol_spritz 0.18 container,filled
caipirinha/highball/gin_tonic/rum_punch 0.18 container,filled
teabag/tea_bag 0.07 flat
sugar_cube/ice_cube 0.02
# --- tableware and kitchen ---
fried_egg 0.12 flat
dumpling/gyoza/wonton/meatball 0.045
dough/batter/clay/playdough/foam/styrofoam 0.2 soft,pierceable
colander/strainer/sieve/measuring_cup/lunchbox/lunch_box 0.2 container
egg_cup 0.05 container
tea_cozy/tea_cosy 0.3 soft,wrap
thermos 0.3 container
grater/peeler/can_opener/bottle_opener/corkscrew/salt_shaker/pepper_shaker/pepper_mill 0.15
tongs 0.3
oven_mitt/pot_holder 0.3 soft,wrap
thermometer/meat_thermometer 0.15 pointed
kitchen_counter/counter/countertop/kitchen_island 2.0 flat
dish_rack/drying_rack 0.45 container
coaster 0.1 flat
decanter/carafe/pitcher/jug/vial/potion_bottle 0.25 container
potion/elixir 0.2 container,filled
ice_bucket/wine_cooler 0.25 container
cocktail_umbrella 0.1 pointed,staked
macaron/truffle 0.04
watering_can 0.4 container
cake_stand 0.3
plate/dish/saucer 0.27 flat,container
bowl 0.2 container
punch_bowl/salad_bowl/mixing_bowl 0.35 container
cup/coffee_cup/teacup/mug/beaker 0.1 container
glass/tumbler/wine_glass/martini_glass/champagne_glass/goblet/champagne_flute/~flute 0.2 container
bottle/wine_bottle/beer_bottle/flask 0.3 container
jar/canister 0.15 container
can/tin/soda_can 0.12 container
teapot/kettle 0.25 container
pot/saucepan/cooking_pot/cauldron 0.3 container
pan/frying_pan/skillet/wok 0.45 container
tray/platter/cutting_board/chopping_board 0.4 flat
lid 0.15
cork/stopper 0.045
straw/drinking_straw 0.2 pointed
stirrer/swizzle_stick/coffee_stirrer/stir_stick/dipper/water_dipper 0.15 pointed
spoon/tablespoon 0.17 pointed
wooden_spoon/cooking_spoon/stirring_spoon 0.3 pointed
teaspoon 0.14 pointed
ladle/serving_spoon 0.3 pointed
fork 0.19 pointed
knife/kitchen_knife/chef_knife/butter_knife/steak_knife/cleaver 0.28 pointed
cake_server/pie_server/cake_lifter 0.25 pointed
chopstick 0.24 pointed
toothpick/cocktail_stick 0.07 pointed,staked
skewer/kebab_stick 0.3 pointed,staked
whisk/spatula/rolling_pin 0.3
napkin/placemat 0.4 flat,soft
tablecloth/table_cloth/tarp/tarpaulin/bedsheet 2.0 flat,soft
blender/mixer/coffee_maker/coffee_machine/espresso_machine 0.4
microwave/microwave_oven 0.5 container
toaster 0.3 container
basket 0.4 container
bucket/pail 0.3 container
# --- bathroom and cosmetics ---
toilet_paper/toilet_roll/toilet_paper_roll/paper_towel_roll 0.11
soap_dish 0.12 container
soap_dispenser/hair_dryer/hairdryer 0.22
towel_rail/towel_bar/towel_rack 0.6
shower_head/showerhead/bath_bomb/cotton_swab/nail_polish 0.08
shower_curtain 1.8 flat,soft
bath_mat/bathmat 0.8 flat,soft
plunger/toilet_brush 0.45
medicine_cabinet 0.6 container
laundry_basket/hamper 0.6 container
lipstick/lip_balm/mascara 0.08 pointed
perfume/perfume_bottle/lotion/shampoo 0.15 container
toothbrush/razor/hairbrush/comb 0.18 pointed
toothpaste/tube 0.18
soap/sponge 0.09 soft
# --- furniture and home ---
computer_mouse/~mouse 0.11
stapler/tape_dispenser/calculator/projector/router 0.2
paperclip/paper_clip/eraser/usb_stick/flash_drive/webcam/rubber_stamp 0.04
binder/folder/file_folder/tablet/ipad 0.3 flat
printer/scanner 0.45
pencil_sharpener/sharpener 0.08 container
alarm_clock/desk_clock 0.12
filing_cabinet/file_cabinet 1.3 container
locker 1.8 container
fan/desk_fan/electric_fan 0.35
ceiling_fan 1.2
bell/cowbell/doorbell 0.12
nightstand/bedside_table/side_table 0.55
pegboard 1.0 flat
anvil 0.5
barrel/keg/cask 0.9 container
lantern/jack_o_lantern 0.3 container
pedestal/plinth 1.0
podium/lectern/music_stand 1.2
coffin/casket 2.0 container
tombstone/gravestone/headstone 1.0
easel/tripod/microphone_stand/mic_stand/lamp_stand 1.7
telescope 1.0
microscope 0.4
microscope_slide/glass_slide/~slide 0.075 flat
microphone/mic 0.2
turntable/record_player 0.45
record/vinyl 0.3 flat
dollhouse 0.8 container
table/dining_table/coffee_table/kitchen_table 1.5
desk/workbench 1.4
chair/stool/armchair/office_chair 0.9
bench 1.5
sofa/couch 2.0
bed 2.1
pillow 0.6 soft
cushion 0.45 soft
blanket/quilt/duvet/rug/carpet/mat/doormat 1.8 flat,soft
towel 0.7 flat,soft
shelf 1.0
bookshelf/bookcase/cabinet/cupboard/wardrobe/closet/dresser 1.8 container
drawer/chest/crate/trunk 0.8 container
box/cardboard_box/carton/package/parcel 0.5 container
present/gift/gift_box 0.35 container
bow/ribbon 0.15
lamp/desk_lamp/table_lamp 0.45
floor_lamp/standing_lamp 1.6
candle 0.2 pointed,staked
sparkler/cake_topper/candle_topper 0.25 pointed,staked
umbrella_stand 0.5 container
snow_globe 0.12 container
candlestick/candle_stick/candle_holder/candelabra 0.3 container
vase 0.3 container
flower_pot/plant_pot/planter/pot_plant 0.25 container
clock/wall_clock 0.35 flat
mirror 0.8 flat
hand_mirror/compact_mirror/pocket_mirror/vanity_mirror 0.25 flat
painting/picture/frame/picture_frame/poster/canvas/map/calendar 0.7 flat
photo/photograph/polaroid 0.15 flat
baking_sheet/baking_tray/sheet_pan 0.4 flat
sign/signboard/plaque 0.6 flat
ornament/decoration/bauble/trinket/knick_knack 0.1
sticker/label/decal/note/sticky_note/postcard/card/playing_card 0.09 flat
letter/paper/sheet/document/page 0.25 flat
envelope 0.22 flat,container
book/notebook/novel 0.25
magazine/newspaper 0.3 flat
television/tv 1.2 flat
monitor/screen 0.6 flat
laptop/computer 0.35
keyboard 0.45
mouse_pad 0.25 flat
phone/smartphone/cellphone/mobile_phone/remote/remote_control 0.15
headphones/headset 0.2
camera 0.12
speaker 0.3
piano/grand_piano 1.5
guitar/violin/cello/bass 1.0
drum 0.5
xylophone/glockenspiel/marimba 0.7
trumpet/flute/saxophone 0.6
drum_stick/drumsticks/~drumstick 0.4 pointed
door/front_door/gate 2.0 flat
window 1.2 flat
shop_window/display_window/storefront 3.0 flat
vending_machine/arcade_machine/jukebox 1.8
wall 4.0 flat,pierceable
floor/ground/platform/stage 5.0 flat
roof 10.0
stair/staircase/step 3.0
fireplace 1.5 container
bathtub/bath 1.7 container
hot_tub/jacuzzi 2.1 container,filled
sink/basin 0.6 container
tap/faucet/spigot/water_tap/garden_tap 0.15
plug/power_plug/charger 0.06
power_strip/extension_cord 0.4
socket/power_outlet/outlet/light_switch 0.1 flat
toilet 0.7 container
shower 2.0
fridge/refrigerator 1.7 container
oven/stove/cooker/washing_machine/dishwasher/dryer/tumble_dryer 0.9 container
trash_can/bin/dustbin/wastebasket 0.6 container
coat_rack/hat_stand/coat_stand 1.8
hook/peg/coat_hook/knob/doorknob/handle 0.06
# small fixings: brackets, hinges, latches
bracket/wall_bracket/shelf_bracket/hinge/latch/hasp/door_latch 0.2
ring_stand/pencil_holder/pen_holder 0.1 container
piggy_bank/money_box 0.2 container
mailbox/letterbox 0.45 container
birdhouse/nest 0.3 container
cage/birdcage 0.6 container
fishbowl/fish_bowl 0.25 container
aquarium/fish_tank 0.8 container
pincushion 0.1 pierceable
dustpan/dust_pan 0.3
ottoman/footstool/pouf 0.6 soft
nozzle/fuel_nozzle/hose_nozzle 0.3
cork_board/corkboard/bulletin_board 0.9 flat,pierceable
whiteboard/blackboard/chalkboard 0.9 flat
board/plank 1.0 flat,pierceable
log/tree_trunk/stump/firewood 0.8 pierceable
# wooden work blocks a blade is struck into
chopping_block/butcher_block/splitting_block/chopping_stump/splitting_stump 0.5 pierceable
wood/timber 0.5 pierceable
block/cube/brick 0.3
amber/resin 0.05
chessboard/chess_board/game_board 0.45 flat
pawn/chess_piece/rook/bishop 0.05
dice/die 0.016
coin 0.025 flat
key 0.06 pointed
lock/padlock/keyhole 0.06 container
bike_lock/cable_lock/chain_lock 0.6 wrap
shoelace/lace 1.0 wrap
# --- clothing and accessories ---
hanger/coat_hanger/clothes_hanger 0.45
clothesline/washing_line 4.0
clothes_peg/clothespin 0.07
wedding_dress/gown/ball_gown 1.5 soft
pajamas/pyjamas/swimsuit/vest/waistcoat 0.7 soft
shoebox/shoe_box 0.35 container
earmuffs 0.2 wrap
hairclip/hair_clip/barrette/hairpin/earring/brooch/badge/button/name_tag/name_badge 0.03 flat
cufflink/tie_clip/tie_pin/collar_stud 0.02
boutonniere/buttonhole/corsage/rosette 0.08
fabric/cloth/felt/linen/cotton/denim/silk/velvet 0.5 flat,soft,pierceable
yarn/ball_of_yarn/yarn_ball/wool 0.1 soft,round
knitting_needle 0.35 pointed
hat/cap/beanie/beret/top_hat/cowboy_hat/sun_hat/fedora/party_hat/witch_hat/wizard_hat/baseball_cap 0.3
crown/tiara 0.2
helmet 0.3
headband/hairband 0.18 wrap
glasses/sunglasses/spectacles/goggles 0.14
mask 0.2
scarf/shawl 0.4 wrap,soft
tie/necktie 0.3 flat
bowtie/bow_tie 0.12 flat
necklace/chain/collar/choker 0.15 wrap
ring 0.02 wrap
bracelet/watch/wristwatch/bangle 0.07 wrap
belt 0.5 wrap
glove/mitten 0.25 wrap
boxing_glove 0.3
sock 0.25 wrap
stocking/christmas_stocking 0.45 soft
shoe/boot/sneaker/slipper/sandal 0.3 container
jacket/coat/shirt/t_shirt/sweater/hoodie/dress/robe/cape/cloak 1.0 soft
raincoat/overcoat/trench_coat/parka/anorak/poncho/mackintosh/duffle_coat 1.0 soft
waders/dungarees/jumpsuit/onesie/wetsuit 1.3 soft,wrap
scrubs/uniform/blouse/tunic/overalls/kimono/lab_coat/cardigan/blazer 1.0 soft
trousers/pants/jeans/skirt/shorts 1.0 soft
apron 0.8 flat,soft
backpack/rucksack/schoolbag 0.5 container,soft
bag/handbag/purse/tote/shopping_bag 0.4 container,soft
suitcase/luggage 0.7 container
wallet 0.11 flat
umbrella/parasol 1.0
cane/walking_stick 1.0 pointed
staff/wizard_staff/quarterstaff 1.7 pointed
saddle/bridle 0.6 soft
wreath/garland 0.5
# --- tools, weapons and equipment ---
drill/power_drill/electric_drill/hair_trimmer 0.25
drill_bit 0.1 pointed
# hooks made to go through what they hold (a coat hook is not)
fishing_hook/fish_hook 0.03 pointed
meat_hook/butcher_hook/gaff 0.15 pointed
toolbox/tool_box/toolkit/tool_chest 0.5 container
vise/vice/clamp 0.3
tape_measure/measuring_tape 0.08
spirit_level/crowbar 0.6
barbell 2.1
dumbbell/kettlebell 0.3
weight_bench/gym_bench 1.5
treadmill/exercise_bike/rowing_machine 1.8
punching_bag/boxing_bag/heavy_bag 1.2 soft
yoga_mat/exercise_mat 1.8 flat,soft
flashlight/torch/glue_gun/paint_roller 0.25
soldering_iron 0.25 pointed
iron/clothes_iron/steam_iron 0.28
ironing_board 1.3 flat
sandpaper 0.25 flat
paint_can/paint_bucket 0.2 container
chainsaw/sawhorse 0.8
trowel 0.3 pointed
hoe 1.5 pointed
shears/pruners/secateurs 0.25
hammer/mallet 0.33
gavel 0.25
sound_block/gavel_block 0.12
axe/hatchet 0.7 pointed
saw/handsaw/hacksaw 0.6 pointed
screwdriver/chisel 0.25 pointed
wrench/spanner/pliers 0.25
nail 0.07 pointed
screw/bolt 0.05 pointed
nut/hex_nut/wing_nut/washer/grommet/eyelet 0.015 container
pin/push_pin/pushpin/thumbtack/tack/needle/sewing_needle 0.03 pointed
piton/spike/tent_peg/ground_spike 0.15 pointed
pipette/dropper/burette 0.15 pointed
test_tube/graduated_cylinder 0.15 container
scissors 0.2
pen/pencil/marker/crayon 0.15 pointed
paintbrush/brush 0.22 pointed
syringe/injection 0.12 pointed
wedge 0.15 pointed
palette 0.35 flat
paddle/oar 2.0
wafer 0.08 flat
ruler 0.3 flat
shovel/spade/rake/broom/broomstick/mop/pitchfork/garden_fork/digging_fork 1.4 pointed
sword/katana/sabre/saber 1.0 pointed
machete/cutlass/kukri/sickle/scythe 0.6 pointed
dagger 0.35 pointed
spear/lance/javelin/trident 2.0 pointed
arrow/dart 0.75 pointed
longbow 1.5
shield 0.75
gun/pistol/revolver 0.25
rifle 1.0
wand/magic_wand 0.35 pointed
flag/pennant/banner 1.5 pointed,staked
cocktail_flag 0.2 pointed,staked
pole/stake/post/pillar/column 2.5 pointed
stick/twig/rod 0.8 pointed
archery_target/bullseye 1.2 flat,pierceable
dartboard 0.45 flat,pierceable
ladder 3.0
rope/cable/hose/wire 3.0 wrap
chain_link 0.03
tent 3.0 container
sleeping_bag 2.0 flat,soft
ball/football/soccer_ball/basketball/volleyball/beach_ball/globe 0.22 round
tennis_ball/baseball/golf_ball/marble/snowball 0.07 round
balloon 0.3 round
bat/baseball_bat/racket/tennis_racket/golf_club/hockey_stick 0.9
skateboard 0.8 flat
surfboard/paddleboard 2.0 flat
snowboard/skis/ski 1.6 flat
frisbee 0.25 flat
kite 1.0 flat
hoop/basketball_hoop/ring_toss 0.45 container
trophy/medal 0.3
slide/playground_slide 3.0
swing 2.0
seesaw/trampoline 3.0
sandbox/sandpit 2.0 container
sandcastle/sand_castle 0.4 pierceable
snowman 1.5 pierceable
goal/soccer_goal/football_goal 7.3
net/goal_net 3.0 soft
bowling_pin/skittle 0.38
bowling_ball 0.22 round
puck/hockey_puck 0.08 flat
shuttlecock/golf_tee/tee 0.06
ski_pole/trekking_pole 1.2 pointed
antenna/satellite_dish 1.5 pointed
chimney 1.5
cross 1.0
star 0.2
statue/sculpture 2.0
# --- toys and figures ---
spinning_top/yo_yo/yoyo/rubik_cube/slinky 0.06
jigsaw/jigsaw_puzzle/puzzle 0.6 flat
rattle/baby_rattle/jack_in_the_box 0.15
pacifier/dummy/teether 0.06
baby_bottle 0.18 container
diaper/nappy 0.4 soft
bib 0.25 flat,soft
toy_train 0.2
train_set/train_track/toy_track/play_mat/playmat 1.2 flat
toy_box/toy_chest 0.8 container
bouncy_ball/rubber_ball 0.05 round
lego_minifigure/minifigure/minifig 0.04 agent
rocking_horse 1.0
water_gun/squirt_gun 0.25
garden_gnome/lawn_gnome 0.35
rubber_duck 0.08
toy/figurine/action_figure/doll/puppet 0.3
teddy_bear/teddy/plush/stuffed_animal 0.4 soft,agent
lego/lego_brick/toy_block 0.05
toy_car 0.1
toy_soldier/tin_soldier/army_man/plastic_soldier 0.06 agent
# --- people and characters (agents) ---
person/human/man/woman/people/adult/guy/lady/gentleman/hiker/farmer/chef/cook/doctor/nurse 1.75 agent
soldier/astronaut/pilot/firefighter/policeman/student/teacher/worker/musician/player/athlete 1.75 agent
dancer/runner/tourist/driver/rider/mannequin/zombie/vampire 1.75 agent
patient/passenger/fisherman/shepherd/gardener/mechanic/plumber/painter/skier/surfer/swimmer/climber 1.75 agent
waiter/waitress/butler/sailor/diver/golfer/boxer/skater/cyclist/artist/scientist/businessman 1.75 agent
groom/bridegroom/bride/best_man/bridesmaid 1.75 agent
boy/girl/kid/child/teen/teenager 1.3 agent
baby/toddler/infant 0.7 agent
king/queen/prince/princess/knight/wizard/witch/pirate/cowboy/ninja/samurai/viking/clown/captain 1.8 agent
superhero/hero/villain/sorcerer/monk/priest/santa/santa_claus/elf/warrior 1.8 agent
dwarf/gnome/goblin 1.0 agent
fairy 0.3 agent
mermaid/merman/centaur/satyr/nymph/genie 1.8 agent
troll/ogre 3.0 agent
robot/android/cyborg 1.8 agent
alien 1.5 agent
captain_america/superman/batman/spider_man/spiderman/iron_man/hulk/thor/wonder_woman 1.8 agent
darth_vader/harry_potter/hermione/gandalf/frodo/luke_skywalker/james_bond/sherlock_holmes/elsa 1.8 agent
snow_white/cinderella/shrek/mario/luigi/link/lara_croft 1.8 agent
pinocchio/peter_pan/alice/tintin 1.2 agent
mickey_mouse/minnie_mouse/donald_duck/goofy/bugs_bunny/daffy_duck/sonic/scooby_doo/garfield 1.0 agent
winnie_the_pooh/pooh/paddington/yoda/pikachu/kermit/stitch/olaf/minion 0.6 agent
# body parts (a person's)
head/mannequin_head/skull 0.25
face 0.2 flat
hand/paw 0.19 pierceable
foot 0.26 pierceable
arm/leg 0.75 pierceable
finger/toe 0.08 pierceable
neck 0.12
nose/ear/mouth/eye 0.05
# --- animals ---
foal/colt/filly 1.4 agent
duckling/chick/gosling/cygnet 0.15 agent
fawn/joey 0.8 agent
perch/bird_perch 0.3
fruit_bat/vampire_bat/~bat 0.3 agent
seal/sea_lion/walrus 2.0 agent
crocodile/alligator 4.0 agent
kangaroo 1.5 agent
turkey/peacock 1.0 agent
dog_bowl/pet_bowl/water_bowl/food_bowl 0.2 container
dog_bed/pet_bed/cat_bed 0.8 soft,container
kennel/doghouse/dog_house 1.0 container
hamster_wheel/exercise_wheel 0.2
hutch/coop/chicken_coop/trough 1.5 container
stable 10.0 container
leash/lead 1.5 wrap
horseshoe 0.12
scarecrow/ghost/skeleton 1.8 agent
dragon/dinosaur 10.0 agent
unicorn 2.4 agent
dog/wolf/fox 0.8 agent
puppy/cub/piglet 0.4 agent
cat 0.45 soft,agent
kitten 0.25 soft,agent
rabbit/bunny/hare 0.4 agent
mouse/rat/hamster/squirrel/guinea_pig 0.1 agent
bird/sparrow/robin/pigeon/crow/songbird 0.2 agent
parrot/macaw/cockatoo/owl 0.4 agent
hen/rooster/duck/goose/penguin 0.5 agent
eagle/hawk/swan/flamingo/heron/stork/crane 1.0 agent
horse/pony/donkey/camel/cow/bull/ox/deer/moose/zebra 2.4 agent
pig/sheep/goat/lamb/calf 1.2 agent
elephant 6.0 agent
giraffe 5.0 agent
lion/tiger/bear/panda/gorilla/leopard/cheetah 2.0 agent
monkey/chimpanzee/lemur/koala/raccoon/otter/sloth 0.6 agent
frog/toad/turtle/tortoise/lizard/crab/lobster 0.2 agent
snail 0.04 agent
snake/python/cobra/eel 2.0 wrap,agent
fish/trout/carp/cod/tuna/pike 0.3 aquatic,agent
jellyfish/octopus/squid/stingray/seahorse 0.3 aquatic,agent
goldfish/clownfish/guppy/angelfish/minnow/tetra 0.06 aquatic,agent
shark/dolphin/whale 4.0 aquatic,agent
butterfly/ladybug/ant/spider/fly/insect/bug/beetle 0.03 agent
bee/bumblebee 0.03 agent,bites
moth 0.02 agent
mosquito/gnat/wasp/hornet/flea/tick/mite/louse/midge/horsefly/bedbug 0.02 agent,bites
worm/earthworm/caterpillar/slug 0.08 agent
beehive/hive/anthill 0.5 container
spider_web/cobweb/web 0.4 flat
oyster/clam/shell/seashell/mussel/scallop 0.1 container
pearl/bead/gem/gemstone/jewel/diamond 0.01 round
bone 0.25
feather 0.2 flat
egg_shell 0.06 container
# --- plants ---
seedling/sprout 0.1
sapling 1.5
lily_pad 0.3 flat
flower_bed/garden_bed/raised_bed 2.0 flat
fence_post 1.2 pointed
sprinkler/bird_feeder 0.25
lawn_mower/lawnmower/mower 1.5
compost_bin 1.0 container
greenhouse/gazebo 4.0 container
hammock 3.0 soft
tree/oak/pine/palm/palm_tree/pine_tree/oak_tree 8.0
treehouse/tree_house/playhouse 2.5 container
field/meadow/vegetable_patch/vegetable_garden/garden_patch/farmland 20.0 flat,pierceable
garden/backyard/yard/orchard/allotment 20.0 flat,pierceable
christmas_tree/xmas_tree/fir 2.0
bush/shrub/hedge 1.5
plant/houseplant/potted_plant/fern/cactus/succulent 0.5
flower/rose/tulip/daisy/sunflower/lily/bouquet 0.4 pointed
leaf 0.1 flat
branch/bough 1.0 pointed
grass/lawn/turf/sod 5.0 flat
rock/stone/boulder 0.5 pierceable
pebble 0.04 round
sand/dirt/soil/snow/mud 5.0 pierceable
# --- vehicles ---
pickup/pickup_truck 5.5 container
tank/battle_tank/army_tank 7.0 container
fuel_tank/gas_tank 0.6 container
fire_truck/fire_engine/ambulance 8.0 container
golf_cart/forklift 2.5
excavator/digger/bulldozer 8.0
construction_crane/tower_crane/~crane 50.0
windshield/windscreen 1.5 flat
windshield_wiper/wiper/license_plate/number_plate 0.5 flat
steering_wheel 0.38
engine/motor/engine_block/gearbox 0.8
roof_rack 1.2
trailer 4.0 container
caravan/camper/rv/motorhome 7.0 container
submarine 50.0
hot_air_balloon 20.0 container
parking_ticket/ticket/receipt/flyer/leaflet 0.15 flat
traffic_light 3.0
bus_stop/bus_shelter 3.0
tire/tyre/wheel 0.7 round
buoy 1.0 round
ufo/flying_saucer 10.0
car/taxi/sedan/suv/jeep/van 4.5 container
truck/lorry/bus/tractor 7.0 container
bicycle/bike/tricycle 1.7
motorcycle/motorbike/scooter 2.0
kick_scooter/push_scooter 0.85
skate/roller_skate 0.3
boat/canoe/kayak/rowboat 5.0 container
ship/yacht/ferry 40.0 container
airplane/plane/aeroplane/jet 30.0
helicopter 12.0
rocket/spaceship 20.0 pointed
train/locomotive/tram 20.0
wagon/cart/wheelbarrow 1.5 container
stroller/pram/buggy 1.0 container
sled/sledge/sleigh 1.5
# --- buildings and places ---
fire_hydrant 0.8
lamp_post/street_lamp/streetlight/lamppost 4.0 pointed
traffic_cone 0.7
hay_bale 1.2 pierceable
haystack 3.0 pierceable
bird_bath/birdbath 0.8 container
house/home/cottage/cabin/hut/shed 10.0 container
garage 6.0 container
barn/warehouse/factory 20.0 container
building/office/school/hospital/hotel/apartment/skyscraper 30.0
church/chapel/temple/mosque/cathedral 25.0
castle/palace/fortress 50.0
tower/castle_tower/lighthouse/turret 15.0
bridge 50.0
fence/railing 2.5 flat
well 1.5 container
fountain/pool/pond/swimming_pool 4.0 container,filled
hot_spring/thermal_pool/onsen/water_hole/watering_hole 6.0 container,filled
lake/river/sea/ocean 100.0 container,filled
stream/creek/brook 20.0 container,filled
harbour/harbor/marina/lagoon/reservoir/canal/fjord/estuary 300.0 container,filled
puddle 0.5 flat,filled
igloo/dome 3.0 container
moon/planet/earth 100.0 round
mountain/hill/cliff 100.0
rock_face/cliff_face/crag/quarry 20.0 pierceable
slope/ski_slope/piste/hillside 100.0 flat,pierceable
glacier/ice_sheet/ice_field/ice_shelf 500.0 pierceable
"""

# A part's size as a fraction of its owner's ("teapot lid": 0.6 of a teapot); a holder named for what it holds
# ("ring box", "guitar case") is sized from that.
PARTS: dict[str, float] = {
    "lid": 0.6, "cap": 0.4, "cover": 1.0, "case": 1.0, "box": 1.5, "sheath": 1.0, "holder": 1.3, "base": 0.7,
    "stand": 0.8, "handle": 0.4, "jar": 0.6, "tank": 0.6, "container": 0.6, "comb": 0.15, "top": 0.5,
    "seat": 0.4, "wheel": 0.3, "door": 0.5, "roof": 1.0, "blade": 0.6, "tip": 0.1, "head": 0.3,
    "leg": 0.5, "shade": 0.4, "bulb": 0.2, "slice": 0.5, "piece": 0.3, "half": 0.8, "wing": 0.4,
    "tail": 0.4, "nose": 0.1, "cube": 0.3, "chunk": 0.3, "stick": 1.0,
}
# A holder of a long thin thing (a toothbrush, a pen, a brush) is a cup shorter than what it holds.
POINTED_HOLDER = 0.6
# Pieces only a food is cut into ("a bread cube", "a carrot stick"; a "wood cube" is a block).
FOOD_PIECES = frozenset({"cube", "chunk", "stick"})
# The parts a person, character or animal has (a "hamster wheel" is no part of a hamster).
AGENT_PARTS = frozenset({"head", "leg", "tail", "wing", "nose", "comb", "tip"})
# The parts a food has, and what holds one (a "pizza box"; a "wheel of cheese" is a whole cheese, no cheese's wheel).
FOOD_PARTS = frozenset({"slice", "piece", "half", "top", "tip", "base", "wing", "leg", "lid", "box", "cube", "chunk",
                        "stick"})
# Holders named for what they hold ("ring box", "pizza box"): only things small enough to be held ("roof box").
HOLDERS = frozenset({"box", "case", "holder"})
HOLDER_MAX_M = 1.2
# Parts made to come off their owner: a name that is only one of these ("lid") is sized from the other object.
DETACHABLE = frozenset({"lid", "cap", "cover", "case", "sheath", "stand", "base", "handle", "top"})
# Parts that hold their owner (a lipstick's cover, a blender's jar) are containers.
CONTAINER_PARTS = frozenset({"cover", "case", "sheath", "holder", "jar", "tank", "container", "cap", "box"})
# Parts that hug their owner's surface (a car cover).
WRAPPING_PARTS = frozenset({"cover"})

# Size adjectives in a name ("ball_small", "BigRock").
SIZE_WORDS: dict[str, float] = {
    "tiny": 0.3, "mini": 0.5, "miniature": 0.3, "small": 0.5, "little": 0.5,
    "big": 2.0, "large": 2.0, "huge": 4.0, "giant": 5.0, "enormous": 5.0,
}

# Materials name the object only when nothing else does ("table wood" is a table, "wood" is wood).
# Substances: an unknown thing named after one ("sand dune", "snow bank") says nothing about its size.
SUBSTANCES = frozenset({"sand", "dirt", "soil", "snow", "mud", "water", "ice", "grass", "hay", "sugar", "salt"})
MATERIALS = frozenset({"wood", "stone", "glass", "metal", "gold", "silver", "plastic", "paper", "marble", "clay",
                       "steel", "iron", "leather", "rock", "fabric", "cloth", "felt", "cotton", "denim", "silk",
                       "velvet", "linen", "wool", "yarn", "oak", "pine", "walnut", "maple", "birch", "teak", "mahogany",
                       "cedar", "bamboo", "brass", "copper", "bronze", "chrome", "porcelain", "ceramic", "rubber",
                       "resin"})


def word_set(text: str) -> frozenset[str]:
    """The whitespace-separated words of a table of words."""
    return frozenset(text.split())


# Words a file name or a prompt puts around an object's head noun that do not name an object: colours, styles,
# file-format and asset-pipeline words ("Rubber_Duck_Yellow", "old_lamp_lowpoly", "SM_Chair_02").
NON_HEAD_WORDS = word_set("""
red green blue yellow white black brown grey gray pink purple beige golden dark light bright pale striped
old new vintage antique modern classic rusty broken clean dirty simple cartoon stylized stylised realistic cute
low high poly lowpoly highpoly hi res detailed model mesh obj fbx glb gltf stl ply sm geo lod copy asset prop
final version var variant wooden metallic plastic ceramic round square tall short long wide empty open closed
""")


@dataclass(frozen=True)
class Entry:
    """One table row: the canonical name (first alias), its longest side in metres and its tags."""

    name: str
    size_m: float
    tags: frozenset[str]
    domain: str = ""  # the table section: "animals", "vehicles" ...


@dataclass(frozen=True)
class Match:
    """What a name resolved to: the matched phrase, its size after part/adjective scaling, tags, how."""

    phrase: str
    entry: Entry  # the head's row; for a part ("teapot lid"), the owner's
    size_m: float
    tags: frozenset[str]
    how: str  # e.g. "lid of a teapot (0.6 x 0.25 m)"

    def has(self, tag: str) -> bool:
        return tag in self.tags


def _parse_table(text: str) -> tuple[dict[str, Entry], dict[str, list[Entry]]]:
    """Rows to (alias -> entry, word -> its senses, the plain row first): ``~word`` in a row adds a sense."""
    table: dict[str, Entry] = {}
    senses: dict[str, list[Entry]] = {}
    domain = ""
    for line in text.splitlines():
        line = line.strip()
        if line.startswith("# ---"):
            domain = line.strip("#- ")
        if not line or line.startswith("#"):
            continue
        names, size, *tags = line.split()
        aliases = [a.replace("_", " ") for a in names.split("/")]
        entry = Entry(aliases[0], float(size), frozenset(tags[0].split(",")) if tags else frozenset(), domain)
        for alias in aliases:
            if alias.startswith("~"):
                senses.setdefault(alias[1:], []).append(entry)
                continue
            if alias in table:
                raise ValueError(f"lexicon alias {alias!r} listed twice")
            table[alias] = entry
    return table, {word: [table[word], *others] for word, others in senses.items()}


LEXICON, SENSES = _parse_table(_TABLE)
MAX_WORDS = max(len(k.split()) for k in LEXICON)

_IRREGULAR = {
    "people": "person", "men": "man", "women": "woman", "children": "child", "teeth": "tooth", "feet": "foot",
    "mice": "mouse", "geese": "goose", "knives": "knife", "leaves": "leaf", "loaves": "loaf", "wolves": "wolf",
    "shelves": "shelf", "halves": "half", "scarves": "scarf", "calves": "calf", "cacti": "cactus",
}


def singulars(word: str) -> list[str]:
    """The word and its plausible English singulars, most likely first ("boxes" -> box, boxe)."""
    if word in _IRREGULAR:
        return [_IRREGULAR[word], word]
    forms = [word]
    if len(word) > 3 and word.endswith("s") and not word.endswith(("ss", "us", "is")):
        if word.endswith("ies"):
            forms.append(word[:-3] + "y")
        if word.endswith("es"):
            forms.append(word[:-2])
        forms.append(word[:-1])
    return forms


def forms(tokens: Iterable[str]) -> set[str]:
    """All the forms ``singulars`` gives of the tokens: to match words whatever their number."""
    return {form for token in tokens for form in singulars(token)}


def words(text: str) -> list[str]:
    """Lower-case word tokens of a file-style or prose name ("CoffeeCup_02" -> ["coffee", "cup"])."""
    text = unicodedata.normalize("NFKD", text).encode("ascii", "ignore").decode()  # "Ståtue" -> "Statue"
    text = re.sub(r"(?<=[a-z])(?=[A-Z])", " ", text)  # camelCase
    text = re.sub(r"['’]s\b", " ", text)  # possessive: "the ball's head"
    return re.findall(r"[a-z]+", text.lower())


def phrase_entry(tokens: list[str]) -> tuple[str, Entry] | None:
    """(matched phrase, entry) for a token run, trying the last word's singulars and the run as one word."""
    for last in singulars(tokens[-1]):
        form = [*tokens[:-1], last]
        for candidate in (" ".join(form), "".join(form)):
            if candidate in LEXICON:
                return candidate, LEXICON[candidate]
    return None


def spans(tokens: list[str]) -> list[tuple[int, int, str, Entry]]:
    """Known phrases in ``tokens`` as (start, end, phrase, entry): longest match first, left to right."""
    found, i = [], 0
    while i < len(tokens):
        for n in range(min(MAX_WORDS + 1, len(tokens) - i), 0, -1):
            hit = phrase_entry(tokens[i:i + n])
            if hit is not None:
                found.append((i, i + n, *hit))
                i += n
                break
        else:
            i += 1
    return found


def bare_part(name: str, owner_name: str = "") -> str | None:
    """The detachable part a name is, when nothing else in it is known ("Lid_01" -> "lid", "pot_lid" -> None) or
    its other words are words of its owner's name ("soldering_stand" of a "soldering_iron")."""
    tokens = words(name)
    for i in reversed(range(len(tokens))):
        part = next((w for w in singulars(tokens[i]) if w in DETACHABLE), None)
        if part is not None:
            if any(start <= i < end and end - start > 1 for start, end, _, _ in spans(tokens)):
                return None  # a compound that is an object of its own: "spinning top", "coat stand"
            others = [t for t in tokens[:i] + tokens[i + 1:] if t not in NON_HEAD_WORDS and len(t) > 2]
            return None if set(others) - set(words(owner_name)) else part  # "music stand": not a bare part
    return None


def lookup(name: str) -> Match | None:
    """Resolve an object name to a size, or None when nothing in it is known.

    The head of an English compound is its last noun ("coffee cup" is a cup), so the rightmost known
    phrase wins (materials, wood species and metals included, only when alone: "CoffeeTable_Oak_02" is a
    coffee table); a last word naming a part after a known owner ("teapot
    lid", "blender_tank") is sized as a fraction of the owner. Size adjectives in the name
    ("ball_small") scale the result; colours, styles and file-pipeline words ("_lowpoly", "_Yellow")
    are not heads. An unknown last word is the head all the same: a closed compound ends in a known
    word ("shoebox" is a box), otherwise the object is named after the known word before it ("pencil
    sharpener"): its size is a guess from that word, and none of that word's shape tags apply.
    """
    tokens = [t for t in words(name) if t not in SIZE_WORDS]
    scale = 1.0
    for token in words(name):
        scale *= SIZE_WORDS.get(token, 1.0)
    while tokens and (tokens[-1] in NON_HEAD_WORDS or len(tokens[-1]) < 3):
        tokens.pop()
    known = spans(tokens)
    found = [f for f in known if f[2] not in MATERIALS] or known
    part = next((w for w in singulars(tokens[-1]) if w in PARTS), None) if tokens else None
    if part is not None and not any(end == len(tokens) and end - start > 1 for start, end, _, _ in found):
        owners = [f for f in found if f[1] < len(tokens) and (part in AGENT_PARTS or "agent" not in f[3].tags)
                  and (part in FOOD_PARTS or f[3].domain != "food and drink")
                  and (part not in HOLDERS or f[3].size_m <= HOLDER_MAX_M)
                  and (part not in FOOD_PIECES or f[3].domain == "food and drink")]
        if owners:
            _, _, phrase, owner = owners[-1]
            fraction = POINTED_HOLDER if part == "holder" and "pointed" in owner.tags else PARTS[part]
            size = owner.size_m * fraction * scale
            tags = frozenset({"container"}) if part in CONTAINER_PARTS else frozenset()
            tags |= {"wrap"} if part in WRAPPING_PARTS else set()
            return Match(part, owner, size, tags, f"{part} of a {phrase} ({fraction:g} x {owner.size_m:g} m)")
    if tokens and not any(end == len(tokens) for _, end, _, _ in known):
        head_word = tokens[-1]
        closed = closed_compound(head_word)
        if closed is not None:
            phrase, head = closed
            return Match(phrase, head, head.size_m * scale, head.tags,
                         f"'{head_word}': a kind of {phrase} ({head.size_m:g} m)")
        if (not found or found[-1][3].domain == "food and drink" or "agent" in found[-1][3].tags
                or found[-1][2] in SUBSTANCES | MATERIALS):
            return None  # a "pizza cutter" is not pizza-sized, nor a "spider web" spider-sized, nor a "sand dune" sandy
        start, _, phrase, known = found[-1]
        named = " ".join(tokens[start:])
        how = f"'{named}': unknown '{head_word}' named after a {phrase}, sized like one ({known.size_m:g} m)"
        return Match(named, known, known.size_m * scale, frozenset(), how)
    if not found:
        return None
    _, _, phrase, head = found[-1]
    how = f"'{phrase}' ({head.size_m:g} m)" + (f" x {scale:g} (size word)" if scale != 1.0 else "")
    return Match(phrase, head, head.size_m * scale, head.tags, how)


def closed_compound(word: str) -> tuple[str, Entry] | None:
    """A one-word compound's known head: the longest known word it ends in, after a known stem ("shoe|box") or
    for a head of 5+ letters, after any stem ("hour|glass"); "tur|key" is no key, "stoc|king" no king."""
    for k in range(3, len(word) - 2):
        hit = phrase_entry([word[k:]])
        if hit is not None and (len(word) - k >= 5 or phrase_entry([word[:k]]) is not None):
            return hit
    return None
